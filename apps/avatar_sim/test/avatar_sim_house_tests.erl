%% The smart home as a pure model: people, devices, signals and files.
-module(avatar_sim_house_tests).
-include_lib("eunit/include/eunit.hrl").

-define(T0, 1731690000000).                      % 2024-11-15 17:00 UTC, after sunset in London

model(Opts) ->
    Desc = avatar_sim_desc:example("smart_home.xml"),
    avatar_sim_house:init(maps:merge(#{description => Desc, spool => "/nonexistent/spool"}, Opts), ?T0).

req(Id, Receiver, Type, Params) ->
    #{id => Id, context => request, sender => <<"Emu">>, receiver => Receiver,
      in_reply_to => undefined, timestamp => 0, seq => undefined, epoch => undefined,
      body => #{category => <<"ACTUATOR">>, type => Type, parameters => Params}}.

run(M, From, Until) ->
    lists:foldl(fun(T, {Acc, Es}) ->
                        {Acc1, Es1} = avatar_sim_house:tick(T, Acc),
                        {Acc1, Es ++ [{T, E} || E <- Es1]}
                end, {M, []}, lists:seq(?T0 + From + 100, ?T0 + Until, 100)).

pushes(Type, Es) ->
    [{T - ?T0, C, Ctx, P} || {T, {push, C, Ctx, #{type := Ty, parameters := P}}} <- Es, Ty =:= Type].

val(K, P) -> proplists:get_value(K, P).

act(M, Who, Action) ->
    {ok, M1, Es} = avatar_sim_house:command({act, Who, Action}, ?T0, M),
    {M1, Es}.

%% A person entering a room is motion there: reported at once, repeated, and ended after the quiet time.
motion_test() ->
    {ok, Script} = avatar_sim_script:check([{{offset, 1000}, <<"resident">>, {go, <<"kitchen">>}},
                                            {{delay, 45000}, <<"resident">>, {go, <<"outside">>}}]),
    {_, Es} = run(model(#{script => Script}), 0, 120000),
    Motion = [{T, C, val(<<"Motion">>, P)} || {T, C, event, P} <- pushes(<<"MotionDetected">>, Es)],
    ?assertEqual([{1000, <<"KitchenMotionSensor01">>, <<"yes">>},
                  {31000, <<"KitchenMotionSensor01">>, <<"yes">>},
                  {75900, <<"KitchenMotionSensor01">>, <<"no">>}], Motion).

%% Someone still in a room makes no motion; ReadMotion says whether someone moves now.
still_and_read_motion_test() ->
    M0 = model(#{people => #{<<"resident">> => <<"living">>}}),
    Read = fun(M) ->
                   {_, [{answer, _, feedback, #{parameters := P}}]} =
                       avatar_sim_house:request(req(<<"r">>, <<"LivingMotionSensor01">>, <<"ReadMotion">>, []),
                                                ?T0, M),
                   val(<<"Motion">>, P)
           end,
    ?assertEqual(<<"yes">>, Read(M0)),
    {M1, []} = act(M0, <<"resident">>, still),
    ?assertEqual(<<"no">>, Read(M1)),
    {_, Es} = run(M1, 0, 60000),
    ?assertEqual([], pushes(<<"MotionDetected">>, Es)),
    {M2, []} = act(M1, <<"resident">>, moving),
    {_, Es2} = run(M2, 0, 100),
    ?assertEqual([<<"yes">>], [val(<<"Motion">>, P) || {_, _, _, P} <- pushes(<<"MotionDetected">>, Es2)]).

%% The keypad reports every input; a wrong one is the paper's wrong password input.
keypad_test() ->
    M0 = model(#{}),
    {M1, [{push, <<"DoorKeypad01">>, event, #{type := <<"PasswordInput">>, parameters := P1}}]} =
        act(M0, <<"intruder">>, {keypad, <<"0000">>}),
    ?assertEqual([<<"yes">>, <<"hall">>, <<"1">>],
                 [val(K, P1) || K <- [<<"WrongPassword">>, <<"Room">>, <<"Attempts">>]]),
    {M2, [{push, _, event, #{parameters := P2}}]} = act(M1, <<"intruder">>, {keypad, <<"9999">>}),
    ?assertEqual(<<"2">>, val(<<"Attempts">>, P2)),
    {M3, [{push, _, event, #{parameters := P3}}]} = act(M2, <<"resident">>, {keypad, <<"1234">>}),
    ?assertEqual([<<"no">>, <<"0">>], [val(K, P3) || K <- [<<"WrongPassword">>, <<"Attempts">>]]),
    {M4, []} = act(M3, <<"resident">>, {go, <<"kitchen">>}),
    ?assertMatch({_, []}, act(M4, <<"resident">>, {keypad, <<"1">>})),
    #{keypad := [_, _, _]} = avatar_sim_house:state(?T0, M4).

%% Words said near the microphone arrive as text, unless it was told to stop listening.
voice_test() ->
    M0 = model(#{people => #{<<"resident">> => <<"living">>}}),
    {M1, [{push, <<"LivingMicrophone01">>, event, #{type := <<"VoiceCommand">>, parameters := P}}]} =
        act(M0, <<"resident">>, {say, <<"keep the light on">>}),
    ?assertEqual(<<"keep the light on">>, val(<<"Text">>, P)),
    {_, []} = act(M1, <<"other">>, {say, <<"nobody hears this outside">>}),
    {M2, [{answer, _, feedback, _}]} =
        avatar_sim_house:request(req(<<"l">>, <<"LivingMicrophone01">>, <<"ListenForCommands">>,
                                     [{<<"Listen">>, <<"no">>}]), ?T0, M1),
    ?assertMatch({_, []}, act(M2, <<"resident">>, {say, <<"hello">>})).

%% Switches change the light and say whether anything changed; the log keeps the schedule.
lights_test() ->
    M0 = model(#{}),
    On = req(<<"on">>, <<"KitchenLightSwitch01">>, <<"TurnLightOn">>, []),
    {M1, [{answer, _, feedback, #{type := <<"ACTION FEEDBACK">>, category := <<"ACTUATOR">>, parameters := P}}]} =
        avatar_sim_house:request(On, ?T0, M0),
    ?assertEqual([<<"TurnLightOn">>, <<"done">>, <<"on">>, <<"kitchen">>, <<"yes">>],
                 [val(K, P) || K <- [<<"Service">>, <<"Result">>, <<"Light">>, <<"Room">>, <<"Changed">>]]),
    {M2, [{answer, _, feedback, #{parameters := P2}}]} = avatar_sim_house:request(On, ?T0 + 5, M1),
    ?assertEqual(<<"no">>, val(<<"Changed">>, P2)),
    {M3, _} = avatar_sim_house:request(req(<<"s">>, <<"BedroomSocketSwitch01">>, <<"SwitchSocketOn">>, []),
                                       ?T0 + 10, M2),
    #{lights := #{<<"kitchen">> := on, <<"bedroom">> := on, <<"living">> := off},
      light_log := [#{room := <<"kitchen">>, state := on}, #{room := <<"bedroom">>, state := on}]} =
        avatar_sim_house:state(?T0, M3).

%% The time sensor reports simulated local time, sunset and darkness.
time_test() ->
    M0 = model(#{}),
    {_, [{answer, _, feedback, #{category := <<"SENSOR">>, type := <<"TimeOfDay">>, parameters := P}}]} =
        avatar_sim_house:request(req(<<"t">>, <<"TimeSensor01">>, <<"ReadTime">>, []), ?T0, M0),
    ?assertEqual([<<"2024-11-15">>, <<"17:00">>, <<"yes">>],
                 [val(K, P) || K <- [<<"Date">>, <<"TimeOfDay">>, <<"Dark">>]]),
    <<"16:", _/binary>> = val(<<"Sunset">>, P),
    {_, Es} = run(M0, 0, 180000),
    ?assertEqual([{60000, <<"17:01">>}, {120000, <<"17:02">>}, {180000, <<"17:03">>}],
                 [{T, val(<<"TimeOfDay">>, Ps)} || {T, _, sensor_data, Ps} <- pushes(<<"TimeOfDay">>, Es)]),
    {_, [{push, _, sensor_data, #{type := <<"Sunset">>}}]} =
        avatar_sim_house:bound(<<"TimeSensor01">>, <<"Sunset">>, ?T0, M0).

%% A burst of photos: a file each, progress between them, the ids in the feedback; then an e-mail with them.
photos_and_email_test() ->
    M0 = model(#{people => #{<<"intruder">> => <<"hall">>}}),
    {M1, Es0} = avatar_sim_house:request(req(<<"p">>, <<"HallCamera01">>, <<"TakePhoto">>,
                                             [{<<"Count">>, <<"3">>}, {<<"Interval">>, <<"500">>}]), ?T0, M0),
    {M2, Es1} = run(M1, 0, 2000),
    Es = Es0 ++ [E || {_, E} <- Es1],
    Files = [F || {file, F, <<137, $P, $N, $G, _/binary>>} <- Es],
    ?assertEqual([<<"/nonexistent/spool/photos/photo-0001.png">>,
                  <<"/nonexistent/spool/photos/photo-0002.png">>,
                  <<"/nonexistent/spool/photos/photo-0003.png">>], Files),
    ?assertEqual(2, length([x || {answer, _, progress, _} <- Es])),
    [P] = [Ps || {answer, _, feedback, #{parameters := Ps}} <- Es],
    Ids = val(<<"Photos">>, P),
    ?assertEqual(<<"photo-0001.png,photo-0002.png,photo-0003.png">>, Ids),
    {M3, [{file, Eml, Bytes}, {answer, _, feedback, #{parameters := EP}}]} =
        avatar_sim_house:request(req(<<"e">>, <<"Notifier01">>, <<"SendEmail">>,
                                     [{<<"Subject">>, <<"INTRUSION">>}, {<<"Attachment">>, Ids}]),
                                 ?T0 + 2000, M2),
    ?assertEqual(Eml, val(<<"File">>, EP)),
    <<"/nonexistent/spool/20241115-170002-4.eml">> = Eml,
    ?assertEqual(3, length(binary:matches(Bytes, <<"Content-Type: image/png">>))),
    #{emails := [#{subject := <<"INTRUSION">>, attachments := [_, _, _]}]} = avatar_sim_house:state(?T0, M3),
    {_, [{answer, _, error, #{type := <<"UnknownPhoto">>}}]} =
        avatar_sim_house:request(req(<<"e2">>, <<"Notifier01">>, <<"SendEmail">>,
                                     [{<<"Attachment">>, <<"../../etc/passwd">>}]), ?T0, M3).

%% The speaker answers when it has finished playing, and remembers what it played.
speaker_test() ->
    M0 = model(#{}),
    {M1, []} = avatar_sim_house:request(req(<<"s">>, <<"HallSpeaker01">>, <<"PlaySound">>,
                                            [{<<"Sound">>, <<"alarm">>}, {<<"Duration">>, <<"3000">>}]), ?T0, M0),
    {_, Early} = run(M1, 0, 2900),
    ?assertEqual([], Early),
    {M2, Es} = run(M1, 0, 3000),
    [{3000, {answer, _, feedback, #{parameters := P}}}] = [{T - ?T0, E} || {T, E} <- Es],
    ?assertEqual(<<"alarm">>, val(<<"Played">>, P)),
    #{played := [#{kind := sound, what := <<"alarm">>}]} = avatar_sim_house:state(?T0, M2).

%% An SMS is written to the spool.
sms_test() ->
    {_, [{file, F, Bytes}, {answer, _, feedback, _}]} =
        avatar_sim_house:request(req(<<"s">>, <<"Notifier01">>, <<"SendSMS">>,
                                     [{<<"TextMsg">>, <<"INTRUSION">>}]), ?T0, model(#{})),
    <<"/nonexistent/spool/", _/binary>> = F,
    {_, _} = binary:match(Bytes, <<"INTRUSION">>).
