%% EUnit tests of mqtt_avatar_logic: each rule asserted by its effects,
%% without processes, sockets or a broker.
-module(mqtt_avatar_logic_tests).

-include_lib("eunit/include/eunit.hrl").

-define(E, <<"mqtt-home">>).

%% A light with a JSON state echo, availability, and a motion sensor.
description() ->
    Entry = fun(Cat, Type, Ps) -> #{category => Cat, type => Type, parameters => Ps} end,
    #{entity_id => ?E, api_name => <<>>, entity_type => avatar, context => <<>>,
      components =>
          [#{id => <<"Light">>,
             services => [Entry(<<"ACTUATOR">>, <<"TurnLightOn">>,
                                [{<<"Room">>, <<"kitchen">>},
                                 {<<"MqttCommandTopic">>, <<"l/set">>},
                                 {<<"MqttStateTopic">>, <<"l/state">>},
                                 {<<"MqttCommand">>, <<"json:{\"state\":\"ON\"}">>},
                                 {<<"MqttExpect">>, <<"json:state=ON">>},
                                 {<<"MqttProgress">>, <<"json:state=WARMING">>},
                                 {<<"MqttValue">>, <<"Light=json:state">>},
                                 {<<"MqttMap">>, <<"ON=on OFF=off">>},
                                 {<<"MqttAvailabilityTopic">>, <<"l/availability">>}]),
                          Entry(<<"ACTUATOR">>, <<"Dim">>,
                                [{<<"MqttCommand">>, <<"json:{}">>},
                                 {<<"MqttCommandArgs">>, <<"Level=brightness.level">>},
                                 {<<"MqttExpect">>, <<"none">>}]),
                          Entry(<<"ACTUATOR">>, <<"Blink">>, [])],
             consumes => [Entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>, [{<<"Feedback">>, <<"yes">>}])]},
           #{id => <<"Pir">>,
             services => [Entry(<<"SENSOR">>, <<"ReadMotion">>, [{<<"Motion">>, <<"yes">>}])],
             consumes => [Entry(<<"SENSOR">>, <<"MotionDetected">>,
                                [{<<"Room">>, <<"hall">>},
                                 {<<"MqttStateTopic">>, <<"p/state">>},
                                 {<<"MqttValue">>, <<"Motion=json:occupancy">>},
                                 {<<"MqttAttributes">>, <<"all">>},
                                 {<<"MqttContext">>, <<"Event">>}])]}]}.

row(CE, CC, PE, PC, Cat, Type) ->
    #{consumer => #{entity => CE, component => CC}, provider => #{entity => PE, component => PC},
      category => Cat, type => Type, score => 1, candidates => 1}.

bound() ->
    Row = fun row/6,
    #{bound => [Row(<<"va">>, <<"LightEmu">>, ?E, <<"Light">>, <<"ACTUATOR">>, <<"TurnLightOn">>),
                Row(?E, <<"Light">>, <<"va">>, <<"LightEmu">>, <<"ACTUATOR">>, <<"ACTION FEEDBACK">>),
                Row(?E, <<"Pir">>, <<"va">>, <<"PirEmu">>, <<"SENSOR">>, <<"MotionDetected">>)],
      unbound => [], entities => [<<"va">>, ?E]}.

state() ->
    {ok, Spec} = mqtt_avatar_spec:from_description(description()),
    S0 = mqtt_avatar_logic:new(?E, Spec, 3000, #{timestamp_field => <<"ts">>}),
    {S1, _} = mqtt_avatar_logic:handle({mqtt_status, up}, 0, S0),
    {S2, _} = mqtt_avatar_logic:handle({binding, bound()}, 0, S1),
    S2.

request(Id, Type, Params) ->
    request(Id, Type, Params, request).

request(Id, Type, Params, Ctx) ->
    {signal, #{id => Id, context => Ctx, sender => <<"LightEmu">>, receiver => <<"Light">>,
               in_reply_to => undefined, timestamp => 1, seq => 1, epoch => 1,
               body => #{category => <<"actuator">>, type => Type, parameters => Params}}}.

mqtt(Topic, Payload) -> mqtt(Topic, Payload, false).
mqtt(Topic, Payload, Retain) -> {mqtt, #{topic => Topic, payload => Payload, retain => Retain}}.

sends(Effects) -> [S || {send, S} <- Effects].

%% A request becomes a publish and a timer; the matching echo becomes the
%% feedback (with the echo's time), the timer is cancelled.
request_then_echo_test() ->
    {S1, [{publish, <<"l/set">>, Payload, Key}, {start_timer, Key, 3000}]} =
        mqtt_avatar_logic:handle(request(<<"r1">>, <<"turn light on">>, []), 10, state()),
    ?assertEqual(<<"{\"state\":\"ON\"}">>, iolist_to_binary(Payload)),
    ?assertEqual(1, mqtt_avatar_logic:pending_count(S1)),
    %% Another state does not answer it: it is the light's state, changed
    %% by someone else, an Event to the VA.
    {S1a, [{send, #{context := event, body := #{type := <<"StateChanged">>}}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"state\":\"OFF\"}">>), 20, S1),
    ?assertEqual(1, mqtt_avatar_logic:pending_count(S1a)),
    {S2, [{cancel_timer, Key}, {send, F}]} =
        mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"state\":\"ON\",\"ts\":777}">>), 30, S1a),
    ?assertMatch(#{context := feedback, sender := <<"Light">>, receiver := <<"LightEmu">>,
                   in_reply_to := <<"r1">>, timestamp := 777,
                   body := #{category := <<"ACTUATOR">>, type := <<"ACTION FEEDBACK">>}}, F),
    #{body := #{parameters := Ps}} = F,
    ?assertEqual([{<<"Service">>, <<"TurnLightOn">>}, {<<"Result">>, <<"done">>},
                  {<<"Light">>, <<"on">>}, {<<"Room">>, <<"kitchen">>}], Ps),
    ?assertEqual(0, mqtt_avatar_logic:pending_count(S2)).

%% A progress-shaped state restarts the wait and reaches the VA as Progress.
progress_test() ->
    {S1, _} = mqtt_avatar_logic:handle(request(<<"r1">>, <<"TurnLightOn">>, []), 0, state()),
    {_, [{start_timer, _, 3000}, {send, #{context := progress, in_reply_to := <<"r1">>}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"state\":\"WARMING\"}">>), 5, S1).

%% No echo: the entry is forgotten and reported; nothing is sent (EVATAR's
%% own timeout answers the VA).
echo_timeout_test() ->
    {S1, [_, {start_timer, Key, _}]} =
        mqtt_avatar_logic:handle(request(<<"r1">>, <<"TurnLightOn">>, []), 0, state()),
    {S2, [{problem, #{what := no_state_echo}}]} =
        mqtt_avatar_logic:handle({echo_timeout, Key}, 3000, S1),
    %% The late echo is the light's new state, an Event like any other.
    {_, [{send, #{context := event, receiver := <<"LightEmu">>,
                  body := #{type := <<"StateChanged">>}}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"state\":\"ON\"}">>), 3100, S2).

%% Arguments go into the JSON command at their path; with no echo
%% expected, the broker's PUBACK is the feedback.
arguments_and_puback_test() ->
    {S1, [{publish, <<"l/set">>, Payload, Key}, _]} =
        mqtt_avatar_logic:handle(request(<<"r2">>, <<"Dim">>, [{<<"Level">>, <<"40">>},
                                                                {<<"Other">>, <<"x">>}]), 0, state()),
    ?assertEqual({ok, #{<<"brightness">> => #{<<"level">> => 40}}},
                 evatar_json:decode(iolist_to_binary(Payload))),
    {_, [{cancel_timer, Key}, {send, #{context := feedback, in_reply_to := <<"r2">>}}]} =
        mqtt_avatar_logic:handle({puback, Key}, 5, S1).

%% A request without feedback is published and forgotten.
request_no_feedback_test() ->
    {S1, [{publish, <<"l/set">>, _, undefined}]} =
        mqtt_avatar_logic:handle(request(<<"r3">>, <<"TurnLightOn">>, [], request_no_feedback), 0,
                                 state()),
    ?assertEqual(0, mqtt_avatar_logic:pending_count(S1)).

%% Refusals, each an Error signal to the requester naming the reason.
refusals_test() ->
    Code = fun(Effects) -> [T || {send, #{context := error, body := #{type := T}}} <- Effects] end,
    S = state(),
    {_, E1} = mqtt_avatar_logic:handle(request(<<"a">>, <<"Fly">>, []), 0, S),
    ?assertEqual([<<"UnknownService">>], Code(E1)),
    {_, E2} = mqtt_avatar_logic:handle(request(<<"b">>, <<"Blink">>, []), 0, S),
    ?assertEqual([<<"NotSupported">>], Code(E2)),
    {Down, _} = mqtt_avatar_logic:handle({mqtt_status, down}, 0, S),
    {_, E3} = mqtt_avatar_logic:handle(request(<<"c">>, <<"TurnLightOn">>, []), 0, Down),
    ?assertEqual([<<"BrokerUnavailable">>], Code(E3)),
    {Off, _} = mqtt_avatar_logic:handle(mqtt(<<"l/availability">>, <<"offline">>), 0, S),
    {_, E4} = mqtt_avatar_logic:handle(request(<<"d">>, <<"TurnLightOn">>, []), 0, Off),
    ?assertEqual([<<"DeviceUnavailable">>], Code(E4)),
    {S5, _} = mqtt_avatar_logic:handle(request(<<"e">>, <<"TurnLightOn">>, []), 0, S),
    {_, E5} = mqtt_avatar_logic:handle(request(<<"e">>, <<"TurnLightOn">>, []), 0, S5),
    ?assertEqual([<<"DuplicateRequest">>], Code(E5)).

%% Availability changes are events to the component's partners; the
%% first `online' is the normal state and says nothing.
availability_test() ->
    S = state(),
    {S1, []} = mqtt_avatar_logic:handle(mqtt(<<"l/availability">>, <<"online">>), 0, S),
    {S2, [{send, Off}]} = mqtt_avatar_logic:handle(mqtt(<<"l/availability">>, <<"offline">>), 1000, S1),
    ?assertMatch(#{context := event, sender := <<"Light">>, receiver := <<"LightEmu">>,
                   body := #{category := <<"EVENT">>, type := <<"DeviceDisconnected">>}}, Off),
    {S2, []} = mqtt_avatar_logic:handle(mqtt(<<"l/availability">>, <<"offline">>), 2000, S2),
    {_, [{send, On}]} = mqtt_avatar_logic:handle(mqtt(<<"l/availability">>, <<"ONLINE">>), 61000, S2),
    #{body := #{type := <<"DeviceReconnected">>, parameters := Ps}} = On,
    ?assertEqual(<<"60">>, proplists:get_value(<<"OfflineSeconds">>, Ps)),
    {_, [{problem, #{what := bad_availability, message := M}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"l/availability">>, <<"sleeping">>), 0, S),
    %% It names what came and what was expected.
    ?assertEqual(<<"got 'sleeping', neither the available ('online') nor the not-available "
                   "('offline') payload">>, M).

%% Readings become events (this stream's context) to the bound emulator,
%% with the static Room and the JSON attributes; a retained reading equal
%% to the last one passed on is not sent again.
stream_test() ->
    S = state(),
    {S1, [{send, M}]} = mqtt_avatar_logic:handle(
                          mqtt(<<"p/state">>, <<"{\"occupancy\":true,\"battery\":90,\"ts\":5}">>), 0, S),
    ?assertMatch(#{context := event, sender := <<"Pir">>, receiver := <<"PirEmu">>, timestamp := 5,
                   body := #{type := <<"MotionDetected">>}}, M),
    #{body := #{parameters := Ps}} = M,
    ?assertEqual([{<<"Motion">>, <<"yes">>}, {<<"Battery">>, <<"90">>},
                  {<<"Occupancy">>, <<"yes">>}, {<<"Room">>, <<"hall">>}], Ps),
    {S1, []} = mqtt_avatar_logic:handle(
                 mqtt(<<"p/state">>, <<"{\"occupancy\":true,\"battery\":90,\"ts\":5}">>, true), 0, S1),
    {_, [{send, _}]} = mqtt_avatar_logic:handle(
                         mqtt(<<"p/state">>, <<"{\"occupancy\":true,\"battery\":90,\"ts\":5}">>), 0, S1),
    {_, [{problem, #{what := bad_payload, topic := <<"p/state">>}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"p/state">>, <<"{oops">>), 0, S).

%% A reading that came before the binding reaches the VA when it binds;
%% the read service answers with the last readings.
binding_delivers_last_reading_test() ->
    {ok, Spec} = mqtt_avatar_spec:from_description(description()),
    S0 = mqtt_avatar_logic:new(?E, Spec, 3000),
    {S1, []} = mqtt_avatar_logic:handle(mqtt(<<"p/state">>, <<"{\"occupancy\":false}">>, true), 0, S0),
    {S2, [{send, #{receiver := <<"PirEmu">>, body := #{parameters := [{<<"Motion">>, <<"no">>} | _]}}}]} =
        mqtt_avatar_logic:handle({binding, bound()}, 0, S1),
    Read = {signal, #{id => <<"q">>, context => request, sender => <<"PirEmu">>, receiver => <<"Pir">>,
                      in_reply_to => undefined, timestamp => 1, seq => 1, epoch => 1,
                      body => #{category => <<"SENSOR">>, type => <<"ReadMotion">>, parameters => []}}},
    {_, [{send, #{context := feedback, body := #{type := <<"MotionDetected">>, parameters := Ps}}}]} =
        mqtt_avatar_logic:handle(Read, 0, S2),
    ?assertEqual(<<"done">>, proplists:get_value(<<"Result">>, Ps)),
    ?assertEqual(<<"no">>, proplists:get_value(<<"Motion">>, Ps)).

%% JSON keys become BIL parameter names.
camel_test() ->
    ?assertEqual(<<"LastMotion">>, mqtt_avatar_logic:camel(<<"last_motion">>)),
    ?assertEqual(<<"P2ndFloor">>, mqtt_avatar_logic:camel(<<"2nd floor">>)),
    ?assertEqual(<<"TimeOfDay">>, mqtt_avatar_logic:camel(<<"Time of day">>)),
    ?assertEqual(<<>>, mqtt_avatar_logic:camel(<<"---">>)).

%% ---------------------------------------------------------------------------
%% MqttArgCheck, MqttCode, MqttCommandTemplate, MqttValueTemplate, MqttExtra
%% ---------------------------------------------------------------------------

%% A component whose services check their parameters, one with a local
%% code (the PBKDF2 hash of 4711), one with a command template, and a
%% stream read by a template, with extra parameters.
family_state() ->
    Entry = fun(Cat, Type, Ps) -> #{category => Cat, type => Type, parameters => Ps} end,
    Salt = <<"salt">>,
    Hash = crypto:pbkdf2_hmac(sha256, <<"4711">>, Salt, 1000, 32),
    Code = iolist_to_binary(["pbkdf2-sha256:1000:", binary:encode_hex(Salt), ":",
                             binary:encode_hex(Hash)]),
    D = #{entity_id => ?E, api_name => <<>>, entity_type => avatar, context => <<>>,
          components =>
              [#{id => <<"Dev">>,
                 services => [Entry(<<"ACTUATOR">>, <<"SetMode">>,
                                    [{<<"MqttCommandTopic">>, <<"d/mode">>},
                                     {<<"MqttCommand">>, <<"raw:">>},
                                     {<<"MqttCommandArgs">>, <<"Mode">>},
                                     {<<"MqttArgCheck">>, <<"Mode=off|heat">>},
                                     {<<"MqttExpect">>, <<"none">>}]),
                              Entry(<<"ACTUATOR">>, <<"SetLevel">>,
                                    [{<<"MqttCommandTopic">>, <<"d/level">>},
                                     {<<"MqttCommand">>, <<"raw:">>},
                                     {<<"MqttCommandArgs">>, <<"Level">>},
                                     {<<"MqttArgCheck">>, <<"Level=0..10">>},
                                     {<<"MqttCommandTemplate">>, <<"{\"level\": {{ value * 10 }}}">>},
                                     {<<"MqttExpect">>, <<"none">>}]),
                              Entry(<<"ACTUATOR">>, <<"Arm">>,
                                    [{<<"Code">>, <<"yes">>},
                                     {<<"MqttCommandTopic">>, <<"d/arm">>},
                                     {<<"MqttCommand">>, <<"raw:ARM_AWAY">>},
                                     {<<"MqttCode">>, Code},
                                     {<<"MqttExpect">>, <<"none">>}])],
                 consumes => [Entry(<<"SENSOR">>, <<"Level">>,
                                    [{<<"MqttStateTopic">>, <<"d/state">>},
                                     {<<"MqttValue">>, <<"Level=template">>},
                                     {<<"MqttValueTemplate">>, <<"{{ value_json.tenths / 10 }}">>},
                                     {<<"MqttExtra">>, <<"Unit=dB DeviceClass=sound">>}])]}]},
    {ok, Spec} = mqtt_avatar_spec:from_description(D),
    S0 = mqtt_avatar_logic:new(?E, Spec, 3000),
    {S1, _} = mqtt_avatar_logic:handle({mqtt_status, up}, 0, S0),
    Row = #{consumer => #{entity => ?E, component => <<"Dev">>},
            provider => #{entity => <<"va">>, component => <<"Emu">>},
            category => <<"SENSOR">>, type => <<"Level">>, score => 1, candidates => 1},
    {S2, _} = mqtt_avatar_logic:handle({binding, #{bound => [Row], unbound => []}}, 0, S1),
    S2.

dev_request(Id, Type, Params) ->
    {signal, #{id => Id, context => request, sender => <<"Emu">>, receiver => <<"Dev">>,
               in_reply_to => undefined, timestamp => 1, seq => 1, epoch => 1,
               body => #{category => <<"ACTUATOR">>, type => Type, parameters => Params}}}.

error_of(Effects) ->
    [#{context := error, body := #{type := Code, parameters := [{<<"Message">>, M}]}}] = sends(Effects),
    {Code, M}.

%% A parameter outside its list or range, or missing, is refused with what
%% is allowed, and nothing is published.
arg_check_test() ->
    S = family_state(),
    {_, E1} = mqtt_avatar_logic:handle(dev_request(<<"a1">>, <<"SetMode">>, [{<<"Mode">>, <<"sauna">>}]), 1, S),
    ?assertEqual({<<"BadParameter">>, <<"Mode must be one of: off, heat">>}, error_of(E1)),
    {_, E2} = mqtt_avatar_logic:handle(dev_request(<<"a2">>, <<"SetMode">>, []), 1, S),
    ?assertEqual({<<"BadParameter">>, <<"the request needs parameter Mode">>}, error_of(E2)),
    {_, E3} = mqtt_avatar_logic:handle(dev_request(<<"a3">>, <<"SetLevel">>, [{<<"Level">>, <<"11">>}]), 1, S),
    ?assertEqual({<<"BadParameter">>, <<"Level must be a number from 0 to 10">>}, error_of(E3)),
    {_, [{publish, <<"d/mode">>, P, _} | _]} =
        mqtt_avatar_logic:handle(dev_request(<<"a4">>, <<"SetMode">>, [{<<"Mode">>, <<"HEAT">>}]), 1, S),
    ?assertEqual(<<"HEAT">>, iolist_to_binary(P)).

%% The command template renders what is published, with the value as a
%% number.
command_template_test() ->
    {_, [{publish, <<"d/level">>, P, _} | _]} =
        mqtt_avatar_logic:handle(dev_request(<<"t1">>, <<"SetLevel">>, [{<<"Level">>, <<"7">>}]), 1,
                                 family_state()),
    ?assertEqual(<<"{\"level\": 70}">>, iolist_to_binary(P)).

%% A local code: wrong or missing is WrongCode without a publish; the right
%% one publishes the bare action; the code is in no effect.
local_code_test() ->
    S = family_state(),
    {_, E1} = mqtt_avatar_logic:handle(dev_request(<<"c1">>, <<"Arm">>, [{<<"Code">>, <<"1234">>}]), 1, S),
    ?assertMatch({<<"WrongCode">>, _}, error_of(E1)),
    {_, E2} = mqtt_avatar_logic:handle(dev_request(<<"c2">>, <<"Arm">>, []), 1, S),
    ?assertMatch({<<"WrongCode">>, _}, error_of(E2)),
    {_, E3} = mqtt_avatar_logic:handle(dev_request(<<"c3">>, <<"Arm">>, [{<<"Code">>, <<"4711">>}]), 1, S),
    [{publish, <<"d/arm">>, P, _} | _] = E3,
    ?assertEqual(<<"ARM_AWAY">>, iolist_to_binary(P)),
    [] = [X || X <- E1 ++ E2 ++ E3, binary:match(term_to_binary(X), <<"4711">>) =/= nomatch].

%% A value template reads the stream's value; the extra parameters ride
%% along; a template that fails on a message is a bad_payload problem.
value_template_and_extra_test() ->
    S = family_state(),
    {_, [{send, #{body := #{parameters := Ps}}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"d/state">>, <<"{\"tenths\": 75}">>), 1, S),
    ?assertEqual([{<<"Level">>, <<"7.5">>}, {<<"Unit">>, <<"dB">>}, {<<"DeviceClass">>, <<"sound">>}], Ps),
    {_, [{problem, #{what := bad_payload}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"d/state">>, <<"{\"tenths\": \"many\"}">>), 1, S).

%% ---------------------------------------------------------------------------
%% Actuator state, availability lists, problems (issue 20)
%% ---------------------------------------------------------------------------

%% The light and a second VA component that only watches it (bound to its
%% TurnLightOff).
two_partners() ->
    #{bound := B} = Bound = bound(),
    Bound#{bound := B ++ [row(<<"va">>, <<"Watcher">>, ?E, <<"Light">>, <<"ACTUATOR">>,
                              <<"TurnLightOff">>)]}.

%% A light switched at the wall: every partner gets StateChanged with the
%% new state; the same state again, or a message without the state field,
%% says nothing; the first state known, retained, is no change.
external_state_change_test() ->
    {ok, Spec} = mqtt_avatar_spec:from_description(description()),
    S0 = mqtt_avatar_logic:new(?E, Spec, 3000, #{timestamp_field => <<"ts">>}),
    {S1, []} = mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"state\":\"OFF\"}">>, true), 0, S0),
    {S2, _} = mqtt_avatar_logic:handle({binding, two_partners()}, 0, S1),
    {S3, Effects} = mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"state\":\"ON\",\"ts\":9}">>), 5, S2),
    ?assertEqual([<<"LightEmu">>, <<"Watcher">>], lists:sort([R || #{receiver := R} <- sends(Effects)])),
    [#{context := event, sender := <<"Light">>, timestamp := 9,
       body := #{category := <<"EVENT">>, type := <<"StateChanged">>, parameters := Ps}} | _] =
        sends(Effects),
    ?assertEqual([{<<"Component">>, <<"Light">>}, {<<"Light">>, <<"on">>}, {<<"Room">>, <<"kitchen">>}],
                 Ps),
    {S3, []} = mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"state\":\"ON\"}">>), 6, S3),
    {S3, []} = mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"state\":\"ON\"}">>, true), 6, S3),
    {_, []} = mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"linkquality\":80}">>), 7, S3).

%% The VA's own request: its requester gets the Feedback and no Event;
%% the other partner learns the change by the Event.
own_request_feedback_not_event_test() ->
    {S1, _} = mqtt_avatar_logic:handle({binding, two_partners()}, 0, state()),
    {S2, _} = mqtt_avatar_logic:handle(request(<<"r1">>, <<"TurnLightOn">>, []), 0, S1),
    {_, Effects} = mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{\"state\":\"ON\"}">>), 5, S2),
    ?assertEqual([{feedback, <<"LightEmu">>}, {event, <<"Watcher">>}],
                 [{C, R} || #{context := C, receiver := R} <- sends(Effects)]).

%% An unreadable state payload is bad_payload with no request waiting;
%% one per topic a minute, the next saying how many were left out.
bad_state_payload_test() ->
    S = state(),
    {S1, [{problem, #{what := bad_payload, topic := <<"l/state">>, component := <<"Light">>} = P}]} =
        mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{oops">>), 0, S),
    ?assertNot(maps:is_key(suppressed, P)),
    {S2, []} = mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{oops">>), 1000, S1),
    {S3, []} = mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{oops">>), 2000, S2),
    %% A different mistake is news.
    {_, [{problem, #{what := bad_payload}}]} = mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<255>>), 2000, S3),
    %% Another topic has its own allowance.
    {_, [{problem, #{topic := <<"l/availability">>}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"l/availability">>, <<"maybe">>), 2000, S3),
    {_, [{problem, #{what := bad_payload, suppressed := 2}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"l/state">>, <<"{oops">>), 60000, S3).

%% A component with two availability topics, in each of HA's modes.
avail_state(Mode) ->
    Entry = fun(Cat, Type, Ps) -> #{category => Cat, type => Type, parameters => Ps} end,
    Ps = [{<<"MqttCommandTopic">>, <<"b/set">>}, {<<"MqttCommand">>, <<"raw:ON">>},
          {<<"MqttAvailabilityTopic">>, <<"b/availability">>},
          {<<"MqttAvailabilityValue">>, <<"json:state">>},
          {<<"MqttAvailabilityTopic2">>, <<"bridge/state">>},
          {<<"MqttPayloadAvailable2">>, <<"up">>}, {<<"MqttPayloadNotAvailable2">>, <<"down">>}]
        ++ [{<<"MqttAvailabilityMode">>, Mode} || Mode =/= <<"latest">>],
    D = #{entity_id => ?E, api_name => <<>>, entity_type => avatar, context => <<>>,
          components => [#{id => <<"Light">>, services => [Entry(<<"ACTUATOR">>, <<"TurnLightOn">>, Ps)],
                           consumes => []}]},
    {ok, Spec} = mqtt_avatar_spec:from_description(D),
    #{components := [#{availability := #{mode := _, entries := [_, _]}}]} = Spec,
    {S1, _} = mqtt_avatar_logic:handle({mqtt_status, up}, 0, mqtt_avatar_logic:new(?E, Spec, 3000)),
    {S2, _} = mqtt_avatar_logic:handle({binding, bound()}, 0, S1),
    S2.

%% Feeds availability messages; the availability after each.
avail_trace(Mode, Messages) ->
    {_, Trace} = lists:foldl(
                   fun({T, P}, {S, Acc}) ->
                           {S1, _} = mqtt_avatar_logic:handle(mqtt(T, P), 0, S),
                           {S1, Acc ++ [maps:get(<<"Light">>, mqtt_avatar_logic:availability(S1),
                                                 unknown)]}
                   end, {avail_state(Mode), []}, Messages),
    Trace.

availability_modes_test() ->
    Dev = fun(P) -> {<<"b/availability">>, P} end,
    Bridge = fun(P) -> {<<"bridge/state">>, P} end,
    Msgs = [Bridge(<<"up">>), Dev(<<"{\"state\":\"online\"}">>), Dev(<<"offline">>),
            Bridge(<<"down">>), Dev(<<"{\"state\":\"online\"}">>), Bridge(<<"up">>)],
    %% all: offline while any topic says so (a topic not heard from does
    %% not count); any: online while one says so; latest: the last word.
    ?assertEqual([online, online, offline, offline, offline, online], avail_trace(<<"all">>, Msgs)),
    ?assertEqual([online, online, online, offline, online, online], avail_trace(<<"any">>, Msgs)),
    ?assertEqual([online, online, offline, offline, online, online], avail_trace(<<"latest">>, Msgs)).

%% The bridge going down with the device up is one DeviceDisconnected (mode
%% all), and its return one DeviceReconnected.
availability_all_events_test() ->
    S = avail_state(<<"all">>),
    {S1, []} = mqtt_avatar_logic:handle(mqtt(<<"b/availability">>, <<"{\"state\":\"online\"}">>), 0, S),
    {S2, [{send, #{body := #{type := <<"DeviceDisconnected">>}}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"bridge/state">>, <<"down">>), 0, S1),
    {S3, []} = mqtt_avatar_logic:handle(mqtt(<<"b/availability">>, <<"offline">>), 0, S2),
    {S4, []} = mqtt_avatar_logic:handle(mqtt(<<"bridge/state">>, <<"up">>), 0, S3),
    {_, [{send, #{body := #{type := <<"DeviceReconnected">>}}}]} =
        mqtt_avatar_logic:handle(mqtt(<<"b/availability">>, <<"online">>), 2000, S4).

%% A bad availability mode or a wildcard in a numbered topic is named.
availability_checks_test() ->
    Entry = fun(Ps) -> #{category => <<"ACTUATOR">>, type => <<"X">>, parameters => Ps} end,
    D = fun(Ps) -> #{components => [#{id => <<"C">>, services => [Entry(Ps)], consumes => []}]} end,
    {error, [#{parameter := <<"MqttAvailabilityMode">>}]} =
        mqtt_avatar_spec:from_description(D([{<<"MqttAvailabilityTopic">>, <<"a">>},
                                              {<<"MqttAvailabilityMode">>, <<"most">>}])),
    {error, [#{parameter := <<"MqttAvailabilityTopic3">>}]} =
        mqtt_avatar_spec:from_description(D([{<<"MqttAvailabilityTopic">>, <<"a">>},
                                              {<<"MqttAvailabilityTopic3">>, <<"a/#">>}])),
    {error, [#{parameter := <<"MqttAvailabilityValue">>}]} =
        mqtt_avatar_spec:from_description(D([{<<"MqttAvailabilityTopic">>, <<"a">>},
                                              {<<"MqttAvailabilityValue">>, <<"template">>}])),
    {error, [#{parameter := <<"MqttAvailabilityTopic9">>}]} =
        mqtt_avatar_spec:from_description(D([{<<"MqttAvailabilityTopic9">>, <<"a">>}])).
%% Select options with spaces or `|' (percent-encoded), fan speed ranges
%% (MqttScale), on/off maps of devices writing true/false
%% ---------------------------------------------------------------------------

%% One service setting `Arg' raw on `t/set', checked by `Check', echoed on
%% `t/state', with `More' parameters.
one_service_state(Arg, Check, More) ->
    Entry = fun(Cat, Type, Ps) -> #{category => Cat, type => Type, parameters => Ps} end,
    D = #{entity_id => ?E, api_name => <<>>, entity_type => avatar, context => <<>>,
          components =>
              [#{id => <<"Light">>,
                 services => [Entry(<<"ACTUATOR">>, <<"Set">>,
                                    More ++
                                    [P || {N, _} = P <- [{<<"MqttCommandTopic">>, <<"t/set">>},
                                                         {<<"MqttCommand">>, <<"raw:">>},
                                                         {<<"MqttCommandArgs">>, Arg},
                                                         {<<"MqttArgCheck">>, Check},
                                                         {<<"MqttStateTopic">>, <<"t/state">>},
                                                         {<<"MqttExpect">>, <<"any">>},
                                                         {<<"MqttValue">>, <<Arg/binary, "=raw">>}],
                                          not lists:keymember(N, 1, More)])],
                 consumes => [Entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>, [{<<"Feedback">>, <<"yes">>}])]}]},
    {ok, Spec} = mqtt_avatar_spec:from_description(D),
    S0 = mqtt_avatar_logic:new(?E, Spec, 3000, #{}),
    {S1, _} = mqtt_avatar_logic:handle({mqtt_status, up}, 0, S0),
    {S2, _} = mqtt_avatar_logic:handle({binding, bound()}, 0, S1),
    S2.

publishes(Effects) -> [P || {publish, _, P, _} <- Effects].

error_type(Effects) ->
    [T || #{body := #{category := <<"ERROR">>, type := T}} <- sends(Effects)].

select_options_with_spaces_and_bars_are_checked_test() ->
    Check = <<"Option=", (mqtt_avatar_part:one_of([<<"Radio">>, <<"Spotify Connect">>,
                                                    <<"A|B">>, <<"50%">>]))/binary>>,
    ?assertEqual(<<"Option=Radio|Spotify%20Connect|A%7CB|50%25">>, Check),
    S = one_service_state(<<"Option">>, Check, []),
    Ask = fun(V) -> {_, Effects} = mqtt_avatar_logic:handle(
                                     request(<<"r">>, <<"Set">>, [{<<"Option">>, V}]), 1, S),
                    Effects
          end,
    [?assertEqual([V], publishes(Ask(V))) || V <- [<<"Spotify Connect">>, <<"A|B">>, <<"50%">>,
                                                    <<"radio">>]],
    [?assertEqual({[], [<<"BadParameter">>]}, {publishes(Ask(V)), error_type(Ask(V))})
     || V <- [<<"Cassette">>, <<"Spotify">>, <<"A">>, <<"50%25">>]],
    %% A `%' not followed by two hex digits (hand-written) is itself.
    S2 = one_service_state(<<"Option">>, <<"Option=100%|5%x">>, []),
    [?assertMatch({_, [{publish, _, V, _} | _]},
                  mqtt_avatar_logic:handle(request(<<"r">>, <<"Set">>, [{<<"Option">>, V}]), 1, S2))
     || V <- [<<"100%">>, <<"5%x">>]].

fan_percentage_is_scaled_to_the_speed_range_test() ->
    S = one_service_state(<<"Percentage">>, <<"Percentage=0..100">>,
                          [{<<"MqttScale">>, <<"Percentage=1..10">>}]),
    Pub = fun(Pct) -> {_, Effects} = mqtt_avatar_logic:handle(
                                       request(<<"r">>, <<"Set">>, [{<<"Percentage">>, Pct}]), 1, S),
                      publishes(Effects)
          end,
    %% HA: ceil(percentage * 10 / 100) on the wire.
    ?assertEqual([[<<"6">>], [<<"1">>], [<<"10">>], [<<"0">>], [<<"1">>]],
                 [Pub(P) || P <- [<<"60">>, <<"10">>, <<"100">>, <<"0">>, <<"1">>]]),
    ?assertEqual([], Pub(<<"101">>)),
    Mapping = #{values => [{<<"Percentage">>, raw}], attributes => false, map => [],
                scale => [{<<"Percentage">>, 1, 10}]},
    ?assertEqual([{ok, [{<<"Percentage">>, V}]} || V <- [<<"60">>, <<"10">>, <<"100">>, <<"0">>]],
                 [mqtt_avatar_logic:extract(Mapping, P) || P <- [<<"6">>, <<"1">>, <<"10">>, <<"0">>]]),
    %% A bad MqttScale is a problem of the description.
    Entry = fun(Ps) -> #{category => <<"SENSOR">>, type => <<"X">>, parameters => Ps} end,
    Bad = #{entity_id => ?E, api_name => <<>>, entity_type => avatar, context => <<>>,
            components => [#{id => <<"C">>, services => [],
                             consumes => [Entry([{<<"MqttStateTopic">>, <<"t">>},
                                                 {<<"MqttValue">>, <<"P=raw">>},
                                                 {<<"MqttScale">>, <<"P=10..1">>}])]}]},
    ?assertMatch({error, [#{parameter := <<"MqttScale">>}]}, mqtt_avatar_spec:from_description(Bad)).

on_off_map_of_true_false_devices_test() ->
    Map = fun(On, Off) -> mqtt_avatar_part:on_off_map(#{state_on => On, state_off => Off},
                                                      <<"on">>, <<"off">>)
          end,
    ?assertEqual(<<"true=on yes=on false=off no=off">>, Map(<<"true">>, <<"false">>)),
    ?assertEqual(<<"ON=on OFF=off">>, Map(<<"ON">>, <<"OFF">>)),
    ?assertEqual(<<>>, Map(<<"on">>, <<"off">>)),
    {ok, Spec} = consumes_spec([{<<"MqttStateTopic">>, <<"f">>}, {<<"MqttValue">>, <<"State=raw">>},
                                {<<"MqttMap">>, Map(<<"true">>, <<"false">>)}]),
    #{components := [#{streams := [#{mapping := M}]}]} = Spec,
    ?assertEqual({ok, [{<<"State">>, <<"on">>}]}, mqtt_avatar_logic:extract(M, <<"true">>)),
    ?assertEqual({ok, [{<<"State">>, <<"off">>}]}, mqtt_avatar_logic:extract(M, <<"false">>)).

%% A description refused for a pairing limit: the problem names the option
%% to raise.
refused_description_names_the_option_test() ->
    Refusal = fun(Message) ->
                      {_, [{problem, #{what := evatar_error, message := M}}]} =
                          mqtt_avatar_logic:handle(
                            {signal, #{context => error, in_reply_to => <<"d1">>,
                                       body => #{category => <<"ERROR">>,
                                                 type => <<"DescriptionRefused">>,
                                                 parameters => [{<<"Message">>, Message}]}}},
                            0, state()),
                      M
              end,
    M = Refusal(<<"538 Consumes entries, over the pairing's 256 (max_consumes)">>),
    ?assertMatch({0, _}, binary:match(M, <<"538 Consumes entries">>)),
    ?assertNotEqual(nomatch, binary:match(M, <<"raise the pairing option max_consumes">>)),
    ?assertNotEqual(nomatch, binary:match(Refusal(<<"... 2000000 bytes, over its 1048576 "
                                                    "(max_binding_report)">>),
                                          <<"raise the pairing option max_binding_report">>)),
    ?assertEqual(<<"not bound">>, Refusal(<<"not bound">>)).

%% A lock whose state has a template (not a plain path): the generated
%% Unlock waits for the template's value UNLOCK, so `unlocking' does not
%% finish it; a template that reads nothing of the payload is a problem,
%% not a silent missing state.
lock_with_state_template_is_done_at_unlocked_test() ->
    Tpl = <<"{{ value_json.x if value_json is defined else value }}">>,
    Expect = mqtt_avatar_part:match({template, Tpl}, <<"UNLOCK">>),
    ?assertEqual(<<"template:UNLOCK">>, Expect),
    S = one_service_state(<<"Pin">>, <<"Pin">>,
                          [{<<"MqttExpect">>, Expect}, {<<"MqttValueTemplate">>, Tpl},
                           {<<"MqttValue">>, <<"State=template">>},
                           {<<"MqttMap">>, <<"UNLOCK=unlocked UNLOCKING=unlocking">>}]),
    {S1, [{publish, <<"t/set">>, _, _} | _]} =
        mqtt_avatar_logic:handle(request(<<"r">>, <<"Set">>, [{<<"Pin">>, <<"1">>}]), 1, S),
    {S2, E2} = mqtt_avatar_logic:handle(mqtt(<<"t/state">>, <<"{\"x\":\"UNLOCKING\"}">>), 2, S1),
    ?assertEqual([], [Sg || #{context := feedback} = Sg <- sends(E2)]),
    {_, E3} = mqtt_avatar_logic:handle(mqtt(<<"t/state">>, <<"{\"x\":\"UNLOCK\"}">>), 3, S2),
    [#{body := #{parameters := Ps}}] = [Sg || #{context := feedback} = Sg <- sends(E3)],
    ?assertEqual(<<"unlocked">>, proplists:get_value(<<"State">>, Ps)),
    %% HA's lock example: `{{ value.x }}' on a plain payload reads nothing.
    {ok, Spec} = consumes_spec([{<<"MqttStateTopic">>, <<"l">>},
                                {<<"MqttValue">>, <<"State=template">>},
                                {<<"MqttValueTemplate">>, <<"{{ value.x }}">>}]),
    #{components := [#{streams := [#{mapping := M}]}]} = Spec,
    {error, Why} = mqtt_avatar_logic:extract(M, <<"UNLOCKED">>),
    ?assertNotEqual(nomatch, binary:match(Why, <<"gave nothing">>)).

%% A generated HA sensor as the logic runs it, bound to emulator `Emu'.
sensor_state(Config) ->
    Json = evatar_json:encode(
                              Config#{<<"dev">> => #{<<"ids">> => <<"k1">>,
                                                     <<"name">> => <<"Kitchen">>}}),
    {D, []} = mqtt_avatar:generate([{<<"homeassistant/sensor/k1/t/config">>, Json}], #{}),
    {ok, Spec} = mqtt_avatar_spec:from_description(D#{entity_id => ?E}),
    #{components := [#{id := Id, streams := Streams}]} = Spec,
    Rows = [row(?E, Id, <<"va">>, <<"Emu">>, Cat, Type) || #{category := Cat, type := Type} <- Streams],
    {S1, _} = mqtt_avatar_logic:handle({mqtt_status, up}, 0, mqtt_avatar_logic:new(?E, Spec, 3000)),
    {S2, _} = mqtt_avatar_logic:handle({binding, #{bound => Rows, unbound => [],
                                                   entities => [<<"va">>, ?E]}}, 0, S1),
    {D, S2}.

problems(Effects) -> [P || {problem, P} <- Effects].

%% HA's temperature sensor (device class, unit, state class) is numeric:
%% its streams carry MqttNumeric, and a value that is not a number is not
%% sent, as HA refuses it, but reported once for both streams, naming the
%% value, the topic and why; a different text within the minute is the
%% same problem (limited per topic), counted as suppressed. An empty value
%% or HA's None is no reading; a number passes.
numeric_sensor_refuses_text_test() ->
    {D, S} = sensor_state(#{<<"name">> => <<"Kitchen thermometer">>,
                            <<"device_class">> => <<"temperature">>,
                            <<"unit_of_measurement">> => <<"°C"/utf8>>,
                            <<"state_class">> => <<"measurement">>, <<"state_topic">> => <<"k/t">>}),
    #{components := [#{consumes := Consumes}]} = D,
    ?assertEqual([<<"KitchenThermometer">>, <<"Temperature">>],
                 [proplists:get_value(<<"MqttNumeric">>, Ps) || #{parameters := Ps} <- Consumes]),
    {S1, E1} = mqtt_avatar_logic:handle(mqtt(<<"k/t">>, <<"abc">>), 0, S),
    ?assertEqual([], sends(E1)),
    [#{what := bad_payload, topic := <<"k/t">>, message := M} = P] = problems(E1),
    ?assertNot(maps:is_key(limit, P)),
    ?assertEqual(<<"the value 'abc' on k/t is not a number, and this sensor's readings must be "
                   "numbers (device class temperature, unit °C, state class measurement, as in "
                   "Home Assistant): not sent (docs/mqtt.md section 3.3, MqttNumeric)"/utf8>>, M),
    {S2, E2} = mqtt_avatar_logic:handle(mqtt(<<"k/t">>, <<"warm">>), 1000, S1),
    ?assertEqual({[], []}, {sends(E2), problems(E2)}),
    {S3, E3} = mqtt_avatar_logic:handle(mqtt(<<"k/t">>, <<"">>), 2000, S2),
    {S4, E4} = mqtt_avatar_logic:handle(mqtt(<<"k/t">>, <<"None">>), 2000, S3),
    ?assertEqual([], E3 ++ E4),
    {S5, E5} = mqtt_avatar_logic:handle(mqtt(<<"k/t">>, <<" 21.5 ">>), 3000, S4),
    ?assertEqual([<<"KitchenThermometer">>, <<"Temperature">>],
                 lists:sort([T || #{body := #{type := T}} <- sends(E5)])),
    {_, E6} = mqtt_avatar_logic:handle(mqtt(<<"k/t">>, <<"nan">>), 61000, S5),
    [#{suppressed := 1, message := M6}] = problems(E6),
    ?assertNotEqual(nomatch, binary:match(M6, <<"'nan'">>)),
    [?assert(mqtt_avatar_logic:is_number_text(V))
     || V <- [<<"0">>, <<"-3">>, <<"+2.">>, <<".5">>, <<"1e3">>, <<"-1.5E-2">>, <<"21.5\n">>]],
    [?assertNot(mqtt_avatar_logic:is_number_text(V))
     || V <- [<<"abc">>, <<"nan">>, <<"inf">>, <<"1,5">>, <<".">>, <<"1e">>, <<"0x10">>, <<"yes">>,
              <<"21.5 °C"/utf8>>]].

%% What HA treats as numeric: a unit, a state class or a numeric device
%% class; not a sensor without them, nor the date, enum and timestamp
%% classes, whose values are text.
which_sensors_are_numeric_test() ->
    Numeric = fun(Extra) ->
                      {D, _} = sensor_state(Extra#{<<"name">> => <<"X">>,
                                                   <<"state_topic">> => <<"k/t">>}),
                      #{components := [#{consumes := [#{parameters := Ps} | _]}]} = D,
                      lists:keymember(<<"MqttNumeric">>, 1, Ps)
              end,
    ?assert(Numeric(#{<<"unit_of_measurement">> => <<"W">>})),
    ?assert(Numeric(#{<<"state_class">> => <<"total">>})),
    ?assert(Numeric(#{<<"device_class">> => <<"humidity">>})),
    ?assert(Numeric(#{<<"suggested_display_precision">> => 1})),
    ?assertNot(Numeric(#{})),
    ?assertNot(Numeric(#{<<"device_class">> => <<"timestamp">>})),
    ?assertNot(Numeric(#{<<"device_class">> => <<"enum">>, <<"options">> => [<<"a">>]})),
    %% MqttNumeric must name values MqttValue reads.
    {error, [#{parameter := <<"MqttNumeric">>, message := Why}]} =
        consumes_spec([{<<"MqttStateTopic">>, <<"l">>}, {<<"MqttValue">>, <<"T=raw">>},
                       {<<"MqttNumeric">>, <<"T Temp">>}]),
    ?assertEqual(<<"expected names of values MqttValue reads, not 'Temp'">>, Why).

%% A payload that is not JSON, read by a template that reads value_json
%% (MQTT_REVIEW D9): the problem says so, quoting the payload and the
%% template and naming the topic, not what it led to (an undefined value
%% in `| float'); limited per topic. A template that copes with text
%% (`if value_json is defined') is not a problem; a plain JSON path says
%% the same.
not_json_payload_is_said_as_such_test() ->
    Tpl = <<"{{ value_json.t | float * 1.8 + 32 }}">>,
    {_, S} = sensor_state(#{<<"name">> => <<"Garage">>, <<"state_topic">> => <<"g/c">>,
                            <<"value_template">> => Tpl}),
    {S1, E1} = mqtt_avatar_logic:handle(mqtt(<<"g/c">>, <<"not json">>), 0, S),
    [#{what := bad_payload, topic := <<"g/c">>, message := M}] = problems(E1),
    ?assertEqual(<<"the payload on g/c is not JSON ('not json'; invalid JSON at byte 0: unexpected "
                   "character), but the value template '", Tpl/binary, "' reads it as JSON">>, M),
    {_, E2} = mqtt_avatar_logic:handle(mqtt(<<"g/c">>, <<"still not json">>), 10, S1),
    ?assertEqual([], problems(E2)),
    {_, S3} = sensor_state(#{<<"name">> => <<"Garage">>, <<"state_topic">> => <<"g/c">>,
                             <<"value_template">> =>
                                 <<"{{ value_json.t if value_json is defined else value }}">>}),
    {_, E3} = mqtt_avatar_logic:handle(mqtt(<<"g/c">>, <<"text">>), 0, S3),
    ?assertEqual({[], [<<"text">>]}, {problems(E3), [V || #{body := #{parameters := [{_, V} | _]}}
                                                               <- sends(E3)]}),
    {_, S4} = sensor_state(#{<<"name">> => <<"Garage">>, <<"state_topic">> => <<"g/c">>,
                             <<"value_template">> => <<"{{ value_json.t }}">>}),
    {_, E4} = mqtt_avatar_logic:handle(mqtt(<<"g/c">>, <<"oops">>), 0, S4),
    [#{message := M4}] = problems(E4),
    ?assertEqual(<<"the payload on g/c is not JSON ('oops'; invalid JSON at byte 0: unexpected "
                   "character), but MqttValue Garage=json:t reads it as JSON">>, M4).

%% A description's mistakes are all named at once (MQTT_REVIEW D9: a
%% misspelt MqttCommand hid a bad state topic and MqttArgCheck, and the
%% token was not quoted): the unknown name, the orphaned command
%% parameters, and each bad value, quoting the bad token.
every_description_mistake_at_once_test() ->
    {error, Problems} = entry_spec(services, [{<<"MqttComand">>, <<"raw:on">>},
                                              {<<"MqttCommandTopic">>, <<"c">>},
                                              {<<"MqttStateTopic">>, <<"s/#">>},
                                              {<<"MqttArgCheck">>, <<"Level=0..abc">>},
                                              {<<"MqttExpect">>, <<"sometimes">>}]),
    ?assertEqual([{<<"MqttComand">>, <<"unknown reserved parameter (see docs/mqtt.md section 3)">>},
                  {<<"MqttArgCheck">>, <<"given without MqttCommand (a service without one is a read "
                                         "service, which takes no command parameters)">>},
                  {<<"MqttStateTopic">>, <<"a topic must be non-empty, without + or #">>},
                  {<<"MqttArgCheck">>, <<"expected Param, Param=Min..Max or Param=a|b|c tokens, "
                                         "not 'Level=0..abc'">>},
                  {<<"MqttExpect">>, <<"must be none, any, raw:TEXT, json:PATH=TEXT or template:TEXT">>}],
                 [{N, M} || #{parameter := N, message := M} <- Problems]).

%% The spec (or its problems) of one component with one Consumes entry
%% (or one Service).
consumes_spec(Params) ->
    entry_spec(consumes, Params).

entry_spec(Key, Params) ->
    Entry = #{category => <<"SENSOR">>, type => <<"T">>, parameters => Params},
    mqtt_avatar_spec:from_description(
      (description())#{components => [(#{id => <<"C">>, services => [], consumes => []})#{Key => [Entry]}]}).

%% A zigbee2mqtt siren's StartWarning publishes the warning composite with
%% Strobe as a JSON boolean and Duration as a number; a mode the siren does
%% not have is refused; StopWarning sends mode stop.
zigbee2mqtt_siren_warning_test() ->
    Enum = fun(P, Vs) -> #{<<"type">> => <<"enum">>, <<"property">> => P, <<"name">> => P,
                           <<"access">> => 2, <<"values">> => Vs} end,
    Warning = #{<<"type">> => <<"composite">>, <<"property">> => <<"warning">>,
                <<"name">> => <<"warning">>, <<"access">> => 2,
                <<"features">> =>
                    [Enum(<<"mode">>, [<<"stop">>, <<"burglar">>, <<"fire">>]),
                     Enum(<<"level">>, [<<"low">>, <<"high">>]),
                     #{<<"type">> => <<"binary">>, <<"property">> => <<"strobe">>,
                       <<"name">> => <<"strobe">>, <<"access">> => 2,
                       <<"value_on">> => true, <<"value_off">> => false},
                     #{<<"type">> => <<"numeric">>, <<"property">> => <<"duration">>,
                       <<"name">> => <<"duration">>, <<"access">> => 2}]},
    Dev = #{<<"friendly_name">> => <<"hall_siren">>, <<"ieee_address">> => <<"0x01">>,
            <<"definition">> => #{<<"model">> => <<"SIRZB-110">>, <<"exposes">> => [Warning]}},
    {D, []} = mqtt_avatar:generate([{<<"zigbee2mqtt/bridge/devices">>,
                                     evatar_json:encode([Dev])}],
                                   #{entity_id => ?E}),
    ok = mqtt_avatar_spec:round_trip(D),
    {ok, Spec} = mqtt_avatar_spec:from_description(D),
    [#{id := Id}] = maps:get(components, D),
    {S, _} = mqtt_avatar_logic:handle({mqtt_status, up}, 0, mqtt_avatar_logic:new(?E, Spec, 3000, #{})),
    Request = fun(Type, Params) ->
                      {signal, #{id => <<"r">>, context => request_no_feedback, sender => <<"Va">>,
                                 receiver => Id, in_reply_to => undefined, timestamp => 1, seq => 1,
                                 epoch => 1, body => #{category => <<"actuator">>, type => Type,
                                                       parameters => Params}}}
              end,
    Start = [{<<"Mode">>, <<"burglar">>}, {<<"Level">>, <<"high">>}, {<<"Strobe">>, <<"false">>},
             {<<"Duration">>, <<"10">>}],
    {_, E1} = mqtt_avatar_logic:handle(Request(<<"StartWarning">>, Start), 1, S),
    ?assertEqual([{ok, #{<<"warning">> => #{<<"mode">> => <<"burglar">>, <<"level">> => <<"high">>,
                                            <<"strobe">> => false, <<"duration">> => 10}}}],
                 [evatar_json:decode(iolist_to_binary(P)) || P <- publishes(E1)]),
    {_, E2} = mqtt_avatar_logic:handle(
                Request(<<"StartWarning">>, lists:keystore(<<"Mode">>, 1, Start, {<<"Mode">>, <<"party">>})),
                1, S),
    ?assertEqual([], publishes(E2)),
    {_, E3} = mqtt_avatar_logic:handle(Request(<<"StopWarning">>, []), 1, S),
    ?assertEqual([{ok, #{<<"warning">> => #{<<"mode">> => <<"stop">>}}}],
                 [evatar_json:decode(iolist_to_binary(P)) || P <- publishes(E3)]).
