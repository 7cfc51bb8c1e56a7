%% @doc Internal. The mind of the smart-home VA (paper, section 3.2), pure:
%% it recognises simple and complex activities from its sensor emulators
%% with the rules file, and applies an action policy (holiday, away, sleep:
%% whatever the rules file defines) to each activity and to each time of
%% day the time sensor reports. Photos are taken before the e-mail that
%% carries them; a device that fails does not stop the rest of a policy.
%% Light changes are remembered as the wanted state and applied again when
%% the body comes back after a rebinding.
-module(reference_agents_home).
-behaviour(reference_agents_mind).

-export([init/1, probe/2, choose/3, inspect/1]).
-export([probe_service/2]).

-export_type([args/0]).

-type args() :: #{body := bil:description(),
                  rules := reference_agents_rules:rules(),
                  policy := binary()}.

-record(h, {rules :: reference_agents_rules:rules(),
            policy :: binary(),
            emulators :: reference_agents_emulator:table(),
            recogniser :: reference_agents_activity:state(),
            daytime = reference_agents_daytime:new() :: reference_agents_daytime:daytime(),
            embodied = false :: boolean(),
            next = 1 :: pos_integer(),
            %% Plans waiting for their photos: PlanId -> the e-mails to send.
            plans = #{} :: #{pos_integer() => #{activity := map(), emails := [tuple()]}},
            wanted = #{} :: #{binary() => on | off},
            lights = #{} :: #{binary() => on | off},
            activities = [] :: [map()],
            decisions = [] :: [map()],
            outcomes = [] :: [map()],
            emails = [] :: [binary()]}).

%% ---------------------------------------------------------------------------
%% reference_agents_mind
%% ---------------------------------------------------------------------------

-spec init(args()) -> {ok, #h{}}.
init(#{body := Body, rules := Rules, policy := Policy}) ->
    {ok, #h{rules = Rules, policy = Policy,
            emulators = reference_agents_emulator:new(Body),
            recogniser = reference_agents_activity:new(Rules)}}.

%% @doc Harmless requests that prove each device answers.
-spec probe(reference_agents_emulator:link(), #h{}) -> reference_agents_embodiment:probe().
probe(#{type := Type}, _H) ->
    probe_service(Type, home).

%% @doc The embodiment probe for a smart-home service: read the sensors,
%% switch lights off (they are off in an empty house), a silent chirp on the
%% speaker, listen on. Taking photos, sending messages and switching lights
%% on are not done for a test (they have effects a person notices); the
%% same devices are tested through their other service.
-spec probe_service(binary(), home | room) -> reference_agents_embodiment:probe().
probe_service(Type, _Who) ->
    case reference_agents_activity:keyword(Type) of
        <<"readmotion">> -> {request, []};
        <<"readtime">> -> {request, []};
        <<"readkeypad">> -> {request, []};
        <<"turnlightoff">> -> {request, []};
        <<"switchsocketoff">> -> {request, []};
        <<"listenforcommands">> -> {request, [{<<"Listen">>, <<"yes">>}]};
        <<"playsound">> -> {request, [{<<"Sound">>, <<"chime">>}, {<<"Volume">>, <<"0">>},
                                      {<<"Duration">>, <<"100">>}]};
        <<"takephoto">> -> {request, [{<<"Count">>, <<"1">>}]};
        _ -> skip
    end.

-spec choose(reference_agents_mind:observation(), integer(), #h{}) -> {#h{}, [reference_agents_mind:act()]}.
choose({embodied, _Report}, _Now, H) ->
    %% Read the time at once (sunset, sunrise), and put back the lights the
    %% policy wanted while the body was away.
    TimeActs = case emulator(<<"ReadTime">>, [], H) of
                   [E | _] -> [{request, read_time, E, <<"ReadTime">>, []}];
                   [] -> []
               end,
    Restore = [A || {Room, State} <- lists:sort(maps:to_list(H#h.wanted)),
                    maps:get(Room, H#h.lights, unknown) =/= State,
                    A <- light_acts(Room, State, restore, H)],
    Say = case Restore of
              [] -> [];
              _ -> [{narrate, decide, "body back: switching the lights to what the policy wants"}]
          end,
    {H#h{embodied = true}, TimeActs ++ Say ++ Restore};
choose({disembodied, Why}, _Now, H) ->
    {H#h{embodied = false}, [{narrate, info, ["policy waits: ", Why]}]};
choose({percept, #{service := Service, params := Ps} = P}, Now, H) ->
    case reference_agents_activity:keyword(Service) of
        K when K =:= <<"timeofday">>; K =:= <<"sunset">> -> time_passes(Ps, H);
        _ -> perceive(P, Now, H)
    end;
choose({result, read_time, {ok, Ps}}, _Now, H) ->
    time_passes(Ps, H);
choose({result, read_time, {failed, Why}}, _Now, H) ->
    {H, [{narrate, info, ["could not read the time sensor: ", Why]}]};
choose({result, Tag, Result}, Now, H) ->
    result(Tag, Result, Now, H);
choose({progress, {photos, _Plan}, Ps}, _Now, H) ->
    {H, [{narrate, perceive, ["camera: took ", param(<<"Photo">>, Ps)]}]};
choose({progress, _Tag, _Ps}, _Now, H) ->
    {H, []};
choose({message, From, Message}, _Now, H) ->
    {H, [{narrate, info, io_lib:format("message from ~s ignored: ~0p", [From, Message])}]};
choose({signal, #{context := error, body := #{type := Code, parameters := Ps}}}, _Now, H) ->
    {H, [{narrate, info, ["EVATAR refused a signal: ", Code, " ", param(<<"Message">>, Ps)]}]};
choose({signal, _S}, _Now, H) ->
    {H, []}.

-spec inspect(#h{}) -> map().
inspect(H) ->
    #{policy => H#h.policy, embodied => H#h.embodied,
      minute => reference_agents_daytime:minute(H#h.daytime),
      dark => reference_agents_daytime:dark(H#h.daytime),
      wanted => H#h.wanted, lights => H#h.lights,
      activities => lists:reverse(H#h.activities),
      decisions => lists:reverse(H#h.decisions),
      outcomes => lists:reverse(H#h.outcomes),
      emails => lists:reverse(H#h.emails)}.

%% ---------------------------------------------------------------------------
%% Observe: time and activities
%% ---------------------------------------------------------------------------

time_passes(Ps, #h{daytime = D0} = H) ->
    {D1, Moved} = reference_agents_daytime:update(Ps, D0),
    H1 = H#h{daytime = D1},
    case Moved of
        none ->
            {H1, []};
        {From, To} ->
            Ctx = reference_agents_daytime:context(D1),
            Rules = reference_agents_policy:on_time(H#h.policy, From, To, Ctx, H#h.rules),
            Hour = case To rem 60 of
                       0 -> [{narrate, perceive,
                              io_lib:format("time sensor: ~s, ~s",
                                            [reference_agents_policy:format_minute(To),
                                             case maps:get(dark, Ctx) of
                                                 true -> "dark";
                                                 false -> "daylight"
                                             end])}];
                       _ -> []
                   end,
            lists:foldl(fun(Rule, {HAcc, Acts}) ->
                                {HAcc1, More} = apply_rule(Rule, #{activity => <<"clock">>}, HAcc),
                                {HAcc1, Acts ++ More}
                        end, {H1, Hour}, Rules)
    end.

perceive(#{service := Service, params := Ps, source := Source, time := T}, _Now, H) ->
    Percept = #{service => Service, params => Ps, time => T},
    {R1, Found} = reference_agents_activity:perceive(Percept, H#h.recogniser),
    H1 = H#h{recogniser = R1},
    lists:foldl(
      fun(I, {HAcc, Acts}) ->
              Seen = [{narrate, perceive, describe(I, Source, Ps)}],
              Ctx = reference_agents_daytime:context(HAcc#h.daytime),
              Rules = reference_agents_policy:on_activity(HAcc#h.policy, I, Ctx, HAcc#h.rules),
              HAcc1 = HAcc#h{activities = [summary(I) | HAcc#h.activities]},
              {HAcc2, More} = lists:foldl(fun(Rule, {HA, As}) ->
                                                  {HA1, A1} = apply_rule(Rule, I, HA),
                                                  {HA1, As ++ A1}
                                          end, {HAcc1, []}, Rules),
              {HAcc2, Acts ++ Seen ++ More}
      end, {H1, []}, Found).

describe(#{kind := simple, activity := A, room := Room}, Source, Ps) ->
    io_lib:format("activity ~s~s (~s: ~s)",
                  [A, in_room(Room), Source,
                   lists:join(" ", [[N, "=", V] || {N, V} <- Ps])]);
describe(#{kind := complex, activity := A, room := Room, parts := Parts}, _Source, _Ps) ->
    io_lib:format("complex activity ~s~s: ~s",
                  [A, in_room(Room),
                   lists:join(" + ", [[P, " at ", reference_agents_narrator:format_time(T)]
                                      || #{activity := P, time := T} <- Parts])]).

in_room(any) -> "";
in_room(Room) -> [" in ", Room].

summary(#{activity := A, kind := K, time := T, room := R}) ->
    #{activity => A, kind => K, time => T, room => R}.

%% ---------------------------------------------------------------------------
%% Choose and act: one rule of the policy
%% ---------------------------------------------------------------------------

apply_rule(#{line := Line, actions := Actions} = Rule, Activity, #h{next = Plan} = H) ->
    Decide = {narrate, decide, io_lib:format("policy ~s (rules line ~b)",
                                             [reference_agents_rules:format_rule(Rule), Line])},
    H1 = H#h{next = Plan + 1,
             decisions = [#{line => Line, activity => maps:get(activity, Activity),
                            minute => reference_agents_daytime:minute(H#h.daytime),
                            actions => Actions} | H#h.decisions]},
    Photos = [N || {photos, N} <- Actions],
    {Emails, Now} = lists:partition(fun({email, _, with_photos}) -> Photos =/= [];
                                       (_) -> false
                                    end, Actions),
    H2 = case Emails of
             [] -> H1;
             _ -> H1#h{plans = (H1#h.plans)#{Plan => #{activity => Activity, emails => Emails}}}
         end,
    lists:foldl(fun(A, {HA, Acts}) ->
                        {HA1, More} = action(A, Plan, Activity, HA),
                        {HA1, Acts ++ More}
                end, {H2, [Decide]}, Now).

action({light, Room, State}, Plan, _Activity, H) ->
    Rooms = case Room of
                <<"all">> -> light_rooms(H);
                _ -> [Room]
            end,
    H1 = lists:foldl(fun(R, Acc) -> Acc#h{wanted = (Acc#h.wanted)#{R => State}} end, H, Rooms),
    {H1, lists:append([light_acts(R, State, Plan, H1) || R <- Rooms])};
action({photos, N}, Plan, _Activity, H) ->
    Params = [{<<"Count">>, integer_to_binary(N)}, {<<"Interval">>, <<"1000">>}],
    {H, device(<<"TakePhoto">>, [], {photos, Plan}, Params,
               io_lib:format("take ~b photos", [N]), H)};
action({email, Subject, _}, Plan, Activity, H) ->
    email(Subject, [], <<>>, Plan, Activity, H);
action({sms, Text}, Plan, _Activity, H) ->
    {H, device(<<"SendSMS">>, [], {sms, Plan}, [{<<"TextMsg">>, Text}],
               ["text message \"", Text, "\""], H)};
action(alarm, Plan, _Activity, H) ->
    {H, device(<<"PlaySound">>, [], {alarm, Plan},
               [{<<"Sound">>, <<"alarm">>}, {<<"Volume">>, <<"100">>},
                {<<"Duration">>, <<"3000">>}], "sound the alarm", H)};
action({say, Text}, Plan, _Activity, H) ->
    {H, device(<<"PlayVoiceMessage">>, [], {say, Plan},
               [{<<"Message">>, Text}, {<<"Volume">>, <<"100">>}],
               ["play the message \"", Text, "\""], H)}.

email(Subject, Photos, Note, Plan, Activity, H) ->
    Body = iolist_to_binary(
             [Subject, ": ", describe_for_email(Activity, H), "\n",
              case Photos of
                  [] -> "No photos attached.";
                  _ -> io_lib:format("~b photos attached.", [length(Photos)])
              end, Note, "\n"]),
    Params = [{<<"Subject">>, Subject}, {<<"Body">>, Body}]
        ++ case Photos of
               [] -> [];
               _ -> [{<<"Attachment">>, iolist_to_binary(lists:join(",", Photos))}]
           end,
    {H, device(<<"SendEmail">>, [], {email, Plan}, Params,
               io_lib:format("e-mail \"~s\" with ~b photo(s) attached", [Subject, length(Photos)]),
               H)}.

describe_for_email(#{activity := <<"clock">>}, H) ->
    ["scheduled at ", reference_agents_policy:format_minute(reference_agents_daytime:minute(H#h.daytime))];
describe_for_email(#{activity := A, time := T} = I, _H) ->
    [A, in_room(maps:get(room, I, any)), " at ", reference_agents_narrator:format_time(T),
     " (simulated time, UTC)",
     case maps:get(parts, I, []) of
         [] -> [];
         Parts -> [": ", lists:join(" and ", [[P, in_room(R)] || #{activity := P, room := R} <- Parts])]
     end];
describe_for_email(#{activity := A}, _H) ->
    [A].

light_acts(Room, State, Plan, H) ->
    {On, Off} = case emulator(<<"TurnLightOn">>, [{<<"Room">>, Room}], H) of
                    [_ | _] -> {<<"TurnLightOn">>, <<"TurnLightOff">>};
                    [] -> {<<"SwitchSocketOn">>, <<"SwitchSocketOff">>}
                end,
    Service = case State of on -> On; off -> Off end,
    device(Service, [{<<"Room">>, Room}], {light, Room, State, Plan}, [],
           io_lib:format("switch the ~s light ~s", [Room, State]), H).

light_rooms(H) ->
    Ids = reference_agents_emulator:find(<<"ACTUATOR">>, <<"TurnLightOn">>, [], H#h.emulators)
        ++ reference_agents_emulator:find(<<"ACTUATOR">>, <<"SwitchSocketOn">>, [], H#h.emulators),
    lists:usort([Room || Id <- Ids, {ok, #{consumes := Cs}} <- [reference_agents_emulator:emulator(Id, H#h.emulators)],
                         #{parameters := Ps} <- Cs, {<<"Room">>, Room} <- Ps]).

%% The request to the emulator consuming Service (in the room, if given).
device(Service, Filter, Tag, Params, What, H) ->
    case emulator(Service, Filter, H) of
        [E | _] ->
            [{narrate, act, [What, " (", Service, " via ", E, ")"]},
             {request, Tag, E, Service, Params}];
        [] ->
            [{narrate, act, [What, ": this body has no emulator for ", Service]}]
    end.

emulator(Service, Filter, H) ->
    Category = case Service of
                   <<"Read", _/binary>> -> <<"SENSOR">>;
                   _ -> <<"ACTUATOR">>
               end,
    reference_agents_emulator:find(Category, Service, Filter, H#h.emulators).

%% ---------------------------------------------------------------------------
%% Outcomes
%% ---------------------------------------------------------------------------

result({photos, Plan} = Tag, Result, Now, H) ->
    H1 = outcome(Tag, Result, Now, H),
    {Photos, Note, Say} =
        case Result of
            {ok, Ps} ->
                Ids = [P || P <- binary:split(param(<<"Photos">>, Ps), <<",">>, [global]), P =/= <<>>],
                {Ids, <<>>, {narrate, perceive, ["camera: ", integer_to_binary(length(Ids)),
                                                 " photos taken (", lists:join(", ", Ids), ")"]}};
            {failed, Why} ->
                {[], <<" The camera failed: ", Why/binary>>,
                 {narrate, perceive, ["camera failed: ", Why, "; the e-mail goes without photos"]}}
        end,
    case maps:take(Plan, H1#h.plans) of
        {#{activity := Activity, emails := Emails}, Plans} ->
            lists:foldl(fun({email, Subject, _}, {HA, Acts}) ->
                                {HA1, More} = email(Subject, Photos, Note, Plan, Activity, HA),
                                {HA1, Acts ++ More}
                        end, {H1#h{plans = Plans}, [Say]}, Emails);
        error ->
            {H1, [Say]}
    end;
result({light, Room, State, _Plan} = Tag, {ok, _Ps} = Result, Now, H) ->
    H1 = outcome(Tag, Result, Now, H),
    {H1#h{lights = (H1#h.lights)#{Room => State}},
     [{narrate, perceive, io_lib:format("the ~s light is ~s", [Room, State])}]};
result({email, _Plan} = Tag, {ok, Ps} = Result, Now, H) ->
    H1 = outcome(Tag, Result, Now, H),
    File = param(<<"File">>, Ps),
    {H1#h{emails = [File | H1#h.emails]},
     [{narrate, perceive, ["e-mail written to ", File, " (", param(<<"Attachments">>, Ps),
                           " attachment(s))"]},
      {notify, {email, File}}]};
result(Tag, {ok, Ps} = Result, Now, H) ->
    H1 = outcome(Tag, Result, Now, H),
    {H1, [{narrate, perceive, [what(Tag), ": done", format_params(Ps)]}]};
result(Tag, {failed, Why} = Result, Now, H) ->
    H1 = outcome(Tag, Result, Now, H),
    {H1, [{narrate, perceive, [what(Tag), " FAILED: ", Why, "; the policy carries on"]}]}.

outcome(Tag, Result, Now, H) ->
    H#h{outcomes = [#{time => Now, what => element(1, Tag), tag => Tag,
                      result => case Result of {ok, _} -> ok; {failed, W} -> {failed, W} end}
                    | H#h.outcomes]}.

what({light, Room, State, _}) -> io_lib:format("~s light ~s", [Room, State]);
what({alarm, _}) -> "alarm";
what({say, _}) -> "voice message";
what({sms, _}) -> "text message";
what({email, _}) -> "e-mail";
what({photos, _}) -> "photos";
what(Other) -> io_lib:format("~0p", [Other]).

format_params([]) -> [];
format_params(Ps) -> [" (", lists:join(" ", [[N, "=", V] || {N, V} <- Ps, N =/= <<"Service">>]), ")"].

param(Name, Ps) ->
    case lists:keyfind(Name, 1, Ps) of
        {_, V} -> V;
        false -> <<>>
    end.
