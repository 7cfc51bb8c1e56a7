%% @doc Test support, not a suite: the checks of the holiday evening's
%% outcome (evatar_demo_holiday:run/1) that must hold whether the
%% house's devices are on TCP (evatar_demo_home_SUITE) or on MQTT
%% (evatar_demo_mqtt_SUITE), kept in one place so both assert the same.
-module(evatar_demo_holiday_checks).

-include_lib("stdlib/include/assert.hrl").

-export([intrusion_email_with_photos/2, intrusion_narrated/1, evening_light_schedule/1,
         minute/1]).

%% @doc One e-mail "INTRUSION" in Spool, a real MIME message with the 3 PNG
%% photos of the hall attached, and the VA knows it wrote it.
-spec intrusion_email_with_photos(map(), file:filename()) -> ok.
intrusion_email_with_photos(Outcome, Spool) ->
    #{home := #{emails := Emails, photos := Photos}, va := #{mind := Mind}} = Outcome,
    [#{file := File, subject := <<"INTRUSION">>, attachments := Attached}] = Emails,
    ?assertEqual(3, length(Attached)),
    ?assertEqual(filename:absname(Spool), filename:dirname(binary_to_list(File))),
    {ok, Eml} = file:read_file(File),
    ?assertMatch({match, _}, re:run(Eml, "^Subject: INTRUSION\r?$", [multiline])),
    ?assertEqual(3, length(binary:matches(Eml, <<"Content-Type: image/png">>))),
    [begin
         [PhotoFile] = [F || #{id := I, file := F} <- Photos, I =:= Id],
         {ok, <<137, "PNG", _/binary>>} = file:read_file(PhotoFile)
     end || Id <- Attached],
    %% Photos of the hall taken after the intrusion was recognised.
    ?assertEqual([<<"hall">>], lists:usort([R || #{id := I, room := R} <- Photos,
                                                 lists:member(I, Attached)])),
    #{emails := [File]} = Mind,
    ok.

%% @doc The house VA's story tells, in order, the perceived activities, the
%% complex activity, the policy's decision and the actuations with their
%% outcomes, and the speaker sounded the alarm, then played the message.
%% Returns the VA's story lines for a suite's own checks.
-spec intrusion_narrated(map()) -> [binary()].
intrusion_narrated(Outcome) ->
    #{story := Story, home := #{played := Played}} = Outcome,
    Texts = [T || #{who := <<"house-va">>, text := T} <- Story],
    Expected = [<<"activity failed_authorisation in hall">>,
                <<"complex activity intruder in hall">>,
                <<"policy holiday on intruder do photos 3">>,
                <<"take 3 photos">>,
                <<"camera: 3 photos taken">>,
                <<"e-mail \"INTRUSION\" with 3 photo(s) attached">>,
                <<"e-mail written to ">>],
    ?assertEqual(ok, in_order(Expected, Texts)),
    ?assertMatch([#{kind := sound, what := <<"alarm">>, volume := 100},
                  #{kind := voice, what := <<"You are being recorded.", _/binary>>}],
                 [P || #{volume := V} = P <- Played, V > 0]),
    Texts.

%% @doc The lights changed as the rules file schedules, once each and only
%% those, each change at or after its time and before the next scheduled
%% time.
-spec evening_light_schedule(map()) -> ok.
evening_light_schedule(Outcome) ->
    #{home := #{light_log := Log}} = Outcome,
    Got = [{minute(T), Room, State} || #{time := T, room := Room, state := State} <- Log],
    Want = [{"18:00", <<"living">>, on}, {"19:10", <<"kitchen">>, on},
            {"19:40", <<"kitchen">>, off}, {"20:30", <<"bedroom">>, on},
            {"20:30", <<"living">>, off}, {"22:00", <<"bedroom">>, off}],
    ct:log("~p", [Got]),
    ?assertEqual(lists:sort([{R, S} || {_, R, S} <- Want]), lists:sort([{R, S} || {_, R, S} <- Got])),
    Next = fun(At) -> case [A || {A, _, _} <- Want, A > At] of [N | _] -> N; [] -> "23:59" end end,
    [begin
         [M] = [Mi || {Mi, R, S} <- Got, R =:= Room, S =:= State],
         ?assert(M >= At andalso M < Next(At))
     end || {At, Room, State} <- Want],
    ok.

%% @doc The simulated time Ms as "HH:MM", which sorts as the time does.
-spec minute(integer()) -> string().
minute(Ms) ->
    lists:flatten(string:slice(reference_agents_narrator:format_time(Ms), 0, 5)).

%% ok when each of Expected is part of one of Texts, in that order.
in_order([], _Texts) -> ok;
in_order([E | Es], Texts) ->
    case lists:dropwhile(fun(T) -> binary:match(T, E) =:= nomatch end, Texts) of
        [] -> {missing, E};
        [_ | Rest] -> in_order(Es, Rest)
    end.
