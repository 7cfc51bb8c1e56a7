%% @doc EUnit tests of the pure pairing logic: every rule, by the effects it
%% returns.
-module(evatar_pairing_logic_tests).

-include_lib("eunit/include/eunit.hrl").

-define(P, <<"home">>).
-include_lib("evatar_test_kit/include/evatar_entities.hrl").

%% ---------------------------------------------------------------------------
%% Fixtures
%% ---------------------------------------------------------------------------

config() -> config(#{}).

config(Extra) ->
    {ok, C} = evatar_pairing_logic:config(
                maps:merge(#{agent_credential => <<"agent-secret">>,
                             avatar_credential => <<"avatar-secret">>,
                             join_timeout => 100, feedback_timeout => 200}, Extra)),
    C.

entry(Cat, Type, Params) -> #{category => Cat, type => Type, parameters => Params}.

agent_description() ->
    #{entity_id => ?VA, api_name => <<"VA">>, entity_type => agent, context => <<>>,
      components =>
          [#{id => ?EMU,
             services => [entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>, [{<<"Feedback">>, <<"yes">>}])],
             consumes => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>, [{<<"Light">>, <<"yes">>}])]},
           #{id => ?SINK,
             services => [entry(<<"SENSOR">>, <<"Temperature">>, [])],
             consumes => []}]}.

avatar_description() -> avatar_description([light, thermo]).

avatar_description(Parts) ->
    Light = #{id => ?LIGHT,
              services => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>, [{<<"Light">>, <<"yes">>}])],
              consumes => [entry(<<"ACTUATOR">>, <<"ActionFeedback">>, [{<<"Feedback">>, <<"yes">>}])]},
    Thermo = #{id => ?THERMO,
               services => [entry(<<"SENSOR">>, <<"Status">>, [])],
               consumes => [entry(<<"SENSOR">>, <<"temperature">>, [])]},
    #{entity_id => ?AV, api_name => <<"LIGHT ACTUATOR">>, entity_type => avatar,
      context => <<>>,
      components => [C || {K, C} <- [{light, Light}, {thermo, Thermo}],
                          lists:member(K, Parts)]}.

signal(Id, Context, Sender, Receiver) ->
    signal(Id, Context, Sender, Receiver, undefined).

signal(Id, Context, Sender, Receiver, InReplyTo) ->
    #{id => Id, context => Context, sender => Sender, receiver => Receiver,
      in_reply_to => InReplyTo, timestamp => 1, seq => undefined, epoch => undefined,
      body => entry(<<"ACTUATOR">>, <<"TurnLightOn">>, [])}.

new() -> evatar_pairing_logic:new(?P, config()).

h(Event, St) -> evatar_pairing_logic:handle(Event, 1000, St).

%% Applies an event that must succeed, returning the state only.
ok(Event, St) ->
    {St1, Effects} = h(Event, St),
    ?assertEqual(ok, reply(Effects)),
    St1.

joined() ->
    St = ok({join, agent, ?VA, <<"agent-secret">>}, new()),
    ok({join, avatar, ?AV, <<"avatar-secret">>}, St).

bound() ->
    bound(#{}).

bound(Extra) ->
    St0 = evatar_pairing_logic:new(?P, config(Extra)),
    Joined = ok({join, avatar, ?AV, <<"avatar-secret">>},
                ok({join, agent, ?VA, <<"agent-secret">>}, St0)),
    St = ok({describe, ?VA, agent_description()}, Joined),
    ok({describe, ?AV, avatar_description()}, St).

reply(Effects) ->
    [R] = [R || {reply, R} <- Effects],
    R.

delivered(Effects) -> [{E, S} || {deliver, E, S} <- Effects].
reports(Effects) -> [{E, R} || {report, E, R} <- Effects].
no_logs(Effects) -> [E || E <- Effects, element(1, E) =/= log].

%% ---------------------------------------------------------------------------
%% Configuration
%% ---------------------------------------------------------------------------

config_defaults_test() ->
    {ok, C} = evatar_pairing_logic:config(#{agent_credential => <<"a">>,
                                            avatar_credential => <<"b">>}),
    ?assertMatch(#{join_timeout := 5000, feedback_timeout := 5000, max_avatars := 64}, C).

config_refuses_bad_options_test_() ->
    Base = #{agent_credential => <<"a">>, avatar_credential => <<"b">>},
    [?_assertEqual({error, {bad_option, {join_timeout, -1}}},
                   evatar_pairing_logic:config(Base#{join_timeout => -1})),
     ?_assertEqual({error, {bad_option, {max_avatars, 0}}},
                   evatar_pairing_logic:config(Base#{max_avatars => 0})),
     ?_assertEqual({error, {bad_option, {colour, red}}},
                   evatar_pairing_logic:config(Base#{colour => red})),
     ?_assertEqual({error, {bad_option, {agent_credential, secret}}},
                   evatar_pairing_logic:config(Base#{agent_credential => secret})),
     ?_assertEqual({error, {bad_option, {missing, [avatar_credential]}}},
                   evatar_pairing_logic:config(#{agent_credential => <<"a">>})),
     ?_assertEqual({error, {bad_option, nope}}, evatar_pairing_logic:config(nope))].

%% Every numeric option has a range: its bounds are accepted, one past
%% them is refused naming the option; a timer never reaches
%% erlang:start_timer/3 past its limit (2^32-1 ms).
config_ranges_test_() ->
    Base = #{agent_credential => <<"a">>, avatar_credential => <<"b">>},
    Ranges = evatar:pairing_option_ranges(),
    Keys = [join_timeout, feedback_timeout, resume_timeout, max_avatars, dedup_window,
            max_unacked_out, max_open_requests, max_consumes, max_id_length, max_binding_report],
    [?_assertEqual(lists:sort(Keys), lists:sort(maps:keys(Ranges))),
     ?_assertEqual({0, 4294967295}, maps:get(join_timeout, Ranges)),
     ?_assertEqual({error, {bad_option, {join_timeout, 1000000000000000000000000000000}}},
                   evatar:check_pairing_opts(Base#{join_timeout => 1000000000000000000000000000000}))]
    ++ [?_assertMatch({ok, #{K := Min}}, evatar_pairing_logic:config(Base#{K => Min}))
        || {K, {Min, _}} <- maps:to_list(Ranges)]
    ++ [?_assertMatch({ok, #{K := Max}}, evatar_pairing_logic:config(Base#{K => Max}))
        || {K, {_, Max}} <- maps:to_list(Ranges)]
    ++ [?_assertEqual({error, {bad_option, {K, Max + 1}}}, evatar_pairing_logic:config(Base#{K => Max + 1}))
        || {K, {_, Max}} <- maps:to_list(Ranges)]
    ++ [?_assertEqual({error, {bad_option, {K, Min - 1}}}, evatar_pairing_logic:config(Base#{K => Min - 1}))
        || {K, {Min, _}} <- maps:to_list(Ranges)]
    ++ [?_assertEqual({error, {bad_option, {K, 1.5}}}, evatar_pairing_logic:config(Base#{K => 1.5}))
        || K <- Keys].

%% ---------------------------------------------------------------------------
%% Joining
%% ---------------------------------------------------------------------------

join_starts_the_join_timer_test() ->
    {St, Effects} = h({join, agent, ?VA, <<"agent-secret">>}, new()),
    ?assertEqual([{reply, ok}, {start_timer, {join, ?VA}, 100}], no_logs(Effects)),
    ?assertEqual([?VA], evatar_pairing_logic:entity_ids(St)),
    ?assertEqual(waiting, evatar_pairing_logic:phase(St)).

%% The bridge passes the credential in a map with the client certificate it
%% verified; the role credential is checked the same way.
join_with_auth_map_test_() ->
    Cert = #{sha256 => <<"00ff">>, cn => <<"lamp">>},
    [?_assertEqual(ok, reply(element(2, h({join, agent, ?VA, #{credential => <<"agent-secret">>,
                                                               peer_cert => Cert}}, new())))),
     ?_assertEqual(ok, reply(element(2, h({join, agent, ?VA, #{credential => <<"agent-secret">>,
                                                               peer_cert => undefined}}, new())))),
     ?_assertEqual({error, bad_credential},
                   reply(element(2, h({join, agent, ?VA, #{credential => <<"avatar-secret">>,
                                                           peer_cert => Cert}}, new()))))].

join_refusals_test_() ->
    {ok, OneAvatar} = evatar_pairing_logic:config(#{agent_credential => <<"a">>,
                                                    avatar_credential => <<"v">>,
                                                    max_avatars => 1}),
    Small = ok({join, avatar, <<"x">>, <<"v">>}, evatar_pairing_logic:new(?P, OneAvatar)),
    Refused = fun(Event, St) -> {St1, Effects} = h(Event, St),
                                ?assertEqual(St, St1),
                                reply(Effects)
              end,
    [?_assertEqual({error, bad_credential},
                   Refused({join, agent, ?VA, <<"avatar-secret">>}, new())),
     ?_assertEqual({error, bad_credential},
                   Refused({join, avatar, ?AV, <<"avatar-secret!">>}, new())),
     ?_assertEqual({error, bad_credential}, Refused({join, avatar, ?AV, <<>>}, new())),
     ?_assertEqual({error, occupied},
                   Refused({join, agent, <<"va2">>, <<"agent-secret">>}, joined())),
     ?_assertEqual({error, entity_exists},
                   Refused({join, avatar, ?VA, <<"avatar-secret">>}, joined())),
     ?_assertEqual({error, too_many_entities}, Refused({join, avatar, <<"y">>, <<"v">>}, Small)),
     %% A wrong credential is reported before anything about the pairing.
     ?_assertEqual({error, bad_credential}, Refused({join, agent, ?VA, <<"x">>}, joined())),
     %% The answer is the only effect: the bridge, which asked, logs it.
     ?_assertMatch({_, [{reply, {error, bad_credential}}]},
                   h({join, agent, ?VA, <<"x">>}, new()))].

join_timeout_drops_with_an_error_signal_first_test() ->
    {St, Effects} = h({timeout, {join, ?AV}}, joined()),
    [{deliver, ?AV, Error}, {drop, ?AV, join_timeout, Reason}] = no_logs(Effects),
    ?assertMatch(#{context := error, receiver := ?AV, seq := 1, epoch := 1,
                   body := #{category := <<"ERROR">>, type := <<"JoinTimeout">>}}, Error),
    ?assert(is_binary(Reason)),
    ?assertEqual([?VA], evatar_pairing_logic:entity_ids(St)),
    ?assertMatch(#{dropped := 1}, evatar_pairing_logic:stats(St)),
    %% The id is free again.
    ok({join, avatar, ?AV, <<"avatar-secret">>}, St).

join_timeout_after_registering_does_nothing_test() ->
    St = ok({describe, ?AV, avatar_description()}, joined()),
    ?assertEqual({St, []}, h({timeout, {join, ?AV}}, St)).

%% ---------------------------------------------------------------------------
%% Describing and binding
%% ---------------------------------------------------------------------------

describe_refusals_test_() ->
    St = ok({describe, ?VA, agent_description()}, joined()),
    Refused = fun(Event, S) -> {S1, Effects} = h(Event, S),
                               ?assertEqual(S, S1),
                               {error, Message} = reply(Effects),
                               ?assert(is_binary(Message)),
                               Message
              end,
    Clash = avatar_description(),
    [Light, Thermo] = maps:get(components, Clash),
    [?_assertMatch(<<"EntityID", _/binary>>,
                   Refused({describe, ?AV, (avatar_description())#{entity_id => <<"other">>}}, St)),
     ?_assertMatch(<<"EntityType", _/binary>>,
                   Refused({describe, ?AV, (avatar_description())#{entity_type => agent}}, St)),
     ?_assertMatch(<<"ComponentID 'LightEmulator01' is already used", _/binary>>,
                   Refused({describe, ?AV, Clash#{components => [Light#{id => ?EMU}, Thermo]}}, St)),
     ?_assertMatch(<<"ComponentID 'Thermo01' appears twice">>,
                   Refused({describe, ?AV, Clash#{components => [Thermo, Light#{id => ?THERMO}]}}, St)),
     ?_assertEqual(<<"malformed description">>, Refused({describe, ?AV, #{junk => 1}}, St)),
     ?_assertEqual(<<"malformed description">>,
                   Refused({describe, ?AV, Clash#{components => [#{id => 7}]}}, St)),
     ?_assertMatch(<<"this entity has not joined", _/binary>>,
                   Refused({describe, <<"ghost">>, avatar_description()}, St))].

binding_when_both_sides_registered_test() ->
    {St1, E1} = h({describe, ?VA, agent_description()}, joined()),
    ?assertEqual(ok, reply(E1)),
    ?assert(lists:member({cancel_timer, {join, ?VA}}, E1)),
    ?assertEqual(waiting, evatar_pairing_logic:phase(St1)),
    {St2, E2} = h({describe, ?AV, avatar_description()}, St1),
    ?assertEqual(bound, evatar_pairing_logic:phase(St2)),
    [{?VA, Report}, {?AV, Report}] = reports(E2),
    #{bound := Bound, unbound := Unbound, entities := [?VA, ?AV]} = Report,
    Pairs = lists:sort([{C, P} || #{consumer := #{component := C},
                                    provider := #{component := P}} <- Bound]),
    ?assertEqual([{?LIGHT, ?EMU}, {?EMU, ?LIGHT}, {?THERMO, ?SINK}], Pairs),
    ?assertEqual([], Unbound),
    ?assertEqual(Report, evatar_pairing_logic:bindings(St2)).

unbound_entries_are_reported_test() ->
    Va = agent_description(),
    [Emu, _Sink] = maps:get(components, Va),
    St = ok({describe, ?VA, Va#{components => [Emu]}}, joined()),
    {_, Effects} = h({describe, ?AV, avatar_description()}, St),
    [{?VA, #{unbound := [Unbound]}} | _] = reports(Effects),
    ?assertMatch(#{consumer := #{entity := ?AV, component := ?THERMO},
                   reason := no_provider}, Unbound).

registration_list_test() ->
    St = ok({describe, ?AV, avatar_description()}, joined()),
    [A, B] = evatar_pairing_logic:registration_list(St),
    ?assertMatch(#{entity := ?AV, role := avatar, registered := true}, A),
    ?assertMatch(#{entity := ?VA, role := agent, registered := false,
                   description := undefined}, B).

%% ---------------------------------------------------------------------------
%% Routing
%% ---------------------------------------------------------------------------

request_feedback_round_trip_test() ->
    Req = signal(<<"r1">>, request, ?EMU, ?LIGHT),
    {St1, E1} = h({signal, ?VA, Req}, bound()),
    ?assertEqual([{deliver, ?AV, Req#{seq => 1, epoch => 1}},
                  {start_timer, {feedback, ?EMU, <<"r1">>}, 200}], E1),
    ?assertMatch(#{pending := 1}, evatar_pairing_logic:stats(St1)),
    Fb = signal(<<"f1">>, feedback, ?LIGHT, ?EMU, <<"r1">>),
    {St2, E2} = h({signal, ?AV, Fb}, St1),
    ?assertEqual([{cancel_timer, {feedback, ?EMU, <<"r1">>}},
                  {deliver, ?VA, Fb#{seq => 1, epoch => 1}}], E2),
    ?assertMatch(#{pending := 0, routed := #{request := 1, feedback := 1}},
                 evatar_pairing_logic:stats(St2)).

%% traffic/1 counts each entity's signals in (refused ones too) and out,
%% and the open requests; an entity that leaves takes its count with it.
traffic_counts_signals_in_and_out_test() ->
    Req = signal(<<"r1">>, request, ?EMU, ?LIGHT),
    {St1, _} = h({signal, ?VA, Req}, bound()),
    ?assertMatch(#{pending := 1, entities := #{?VA := #{received := 1, delivered := 0},
                                               ?AV := #{received := 0, delivered := 1}}},
                 evatar_pairing_logic:traffic(St1)),
    Refused = signal(<<"s1">>, sensor_data, ?THERMO, ?EMU),
    {St2, _} = h({signal, ?AV, Refused}, St1),
    {St3, _} = h({signal, ?AV, signal(<<"f1">>, feedback, ?LIGHT, ?EMU, <<"r1">>)}, St2),
    ?assertMatch(#{pending := 0, entities := #{?VA := #{received := 1, delivered := 1},
                                               ?AV := #{received := 2, delivered := 2}}},
                 evatar_pairing_logic:traffic(St3)),
    {St4, _} = h({leave, ?VA, left}, St3),
    ?assertEqual([?AV], maps:keys(maps:get(entities, evatar_pairing_logic:traffic(St4)))).

sensor_stream_is_sequenced_without_timers_test() ->
    Send = fun(N, {St, Acc}) ->
                   S = signal(integer_to_binary(N), sensor_data, ?THERMO, ?SINK),
                   {St1, Effects} = h({signal, ?AV, S}, St),
                   {St1, Acc ++ Effects}
           end,
    {St, Effects} = lists:foldl(Send, {bound(), []}, lists:seq(1, 100)),
    ?assertEqual(lists:seq(1, 100), [Seq || {deliver, ?VA, #{seq := Seq}} <- Effects]),
    ?assertEqual(100, length(Effects)),
    ?assertMatch(#{routed := #{sensor_data := 100}, pending := 0},
                 evatar_pairing_logic:stats(St)).

refusals_go_to_the_sender_only_test_() ->
    Refused = fun(From, Sig, St) ->
                      {St1, Effects} = h({signal, From, Sig}, St),
                      [{deliver, To, Err}] = no_logs(Effects),
                      ?assertEqual(From, To),
                      ?assertMatch(#{context := error, sender := <<"EVATAR">>,
                                     body := #{category := <<"ERROR">>,
                                               parameters := [{<<"Message">>, _}]}}, Err),
                      ?assertEqual(0, maps:get(pending, evatar_pairing_logic:stats(St1))),
                      #{body := #{type := Code}, in_reply_to := InReplyTo} = Err,
                      {Code, InReplyTo}
              end,
    [?_assertEqual({<<"NotBound">>, <<"s1">>},
                   Refused(?AV, signal(<<"s1">>, sensor_data, ?THERMO, ?EMU), bound())),
     ?_assertEqual({<<"UnknownReceiver">>, <<"s2">>},
                   Refused(?VA, signal(<<"s2">>, request, ?EMU, <<"Nowhere">>), bound())),
     ?_assertEqual({<<"BadSender">>, <<"s3">>},
                   Refused(?VA, signal(<<"s3">>, request, ?LIGHT, ?EMU), bound())),
     ?_assertEqual({<<"NotDescribed">>, <<"s4">>},
                   Refused(?VA, signal(<<"s4">>, request, ?EMU, ?LIGHT), joined())),
     ?_assertEqual({<<"BadSignal">>, <<"s5">>},
                   Refused(?VA, #{id => <<"s5">>, sender => ?EMU}, bound())),
     ?_assertEqual({<<"BadSignal">>, <<"s6">>},
                   Refused(?VA, (signal(<<"s6">>, request, ?EMU, ?LIGHT))#{context => shout},
                           bound()))].

duplicate_open_request_is_refused_test() ->
    Req = signal(<<"r1">>, request, ?EMU, ?LIGHT),
    {St1, _} = h({signal, ?VA, Req}, bound()),
    {_, Effects} = h({signal, ?VA, Req}, St1),
    ?assertMatch([{deliver, ?VA, #{body := #{type := <<"DuplicateRequest">>}}}], no_logs(Effects)).

signal_from_a_gone_entity_is_counted_test() ->
    {St, Effects} = h({signal, <<"ghost">>, signal(<<"x">>, event, ?EMU, ?LIGHT)}, bound()),
    ?assertEqual([], Effects),
    ?assertMatch(#{unknown_entity := 1}, evatar_pairing_logic:stats(St)).

%% The requester gets Feedback Timeout, the provider an Event RequestClosed
%% (Reason Timeout), and a Feedback after that is refused NoOpenRequest
%% (docs/protocol.md section 4.3).
feedback_timeout_then_late_feedback_test() ->
    {St1, _} = h({signal, ?VA, signal(<<"r1">>, request, ?EMU, ?LIGHT)}, bound()),
    {St2, E2} = h({timeout, {feedback, ?EMU, <<"r1">>}}, St1),
    [{deliver, ?VA, Timeout}, {deliver, ?AV, Closed}] = no_logs(E2),
    ?assertMatch(#{context := feedback, in_reply_to := <<"r1">>, receiver := ?EMU,
                   body := #{category := <<"EVATAR">>, type := <<"Timeout">>}}, Timeout),
    ?assertMatch(#{context := event, in_reply_to := <<"r1">>, receiver := ?LIGHT,
                   sender := <<"EVATAR">>, origin := evatar,
                   body := #{category := <<"EVATAR">>, type := <<"RequestClosed">>,
                             parameters := [{<<"Reason">>, <<"Timeout">>},
                                            {<<"Message">>, _}]}}, Closed),
    {St3, E3} = h({signal, ?AV, signal(<<"f1">>, feedback, ?LIGHT, ?EMU, <<"r1">>)}, St2),
    ?assertMatch([{deliver, ?AV, #{context := error, in_reply_to := <<"f1">>,
                                   receiver := ?LIGHT, origin := evatar,
                                   body := #{category := <<"ERROR">>,
                                             type := <<"NoOpenRequest">>}}}], no_logs(E3)),
    ?assertMatch(#{timeouts := 1, late_feedback := 1, pending := 0,
                   errors := #{<<"NoOpenRequest">> := 1}},
                 evatar_pairing_logic:stats(St3)),
    %% A timer firing for a closed request changes nothing.
    ?assertEqual({St3, []}, h({timeout, {feedback, ?EMU, <<"r1">>}}, St3)).

progress_extends_the_deadline_test() ->
    {St1, _} = h({signal, ?VA, signal(<<"walk">>, request, ?EMU, ?LIGHT)}, bound()),
    Progress = signal(<<"p1">>, progress, ?LIGHT, ?EMU, <<"walk">>),
    {St2, E2} = evatar_pairing_logic:handle({signal, ?AV, Progress}, 1150, St1),
    ?assertEqual([{deliver, ?VA, Progress#{seq => 1, epoch => 1}},
                  {start_timer, {feedback, ?EMU, <<"walk">>}, 200}], E2),
    ?assertEqual([{{feedback, ?EMU, <<"walk">>}, 200}], evatar_pairing_logic:timers(St2, 1150)),
    {St3, E3} = h({signal, ?AV, signal(<<"f">>, feedback, ?LIGHT, ?EMU, <<"walk">>)}, St2),
    ?assertMatch([{cancel_timer, _}, {deliver, ?VA, #{seq := 2}}], E3),
    ?assertMatch(#{routed := #{progress := 1, feedback := 1}, pending := 0},
                 evatar_pairing_logic:stats(St3)).

feedback_from_another_component_does_not_close_test() ->
    {St1, _} = h({signal, ?VA, signal(<<"r1">>, request, ?EMU, ?LIGHT)}, bound()),
    %% Thermo01 is not bound to the emulator at all.
    {St2, E2} = h({signal, ?AV, signal(<<"f">>, feedback, ?THERMO, ?EMU, <<"r1">>)}, St1),
    ?assertMatch([{deliver, ?AV, #{body := #{type := <<"NotBound">>}}}], no_logs(E2)),
    ?assertMatch(#{pending := 1}, evatar_pairing_logic:stats(St2)).

error_answering_a_request_closes_it_test() ->
    {St1, _} = h({signal, ?VA, signal(<<"r1">>, request, ?EMU, ?LIGHT)}, bound()),
    {St2, E2} = h({signal, ?AV, signal(<<"e">>, error, ?LIGHT, ?EMU, <<"r1">>)}, St1),
    ?assertMatch([{cancel_timer, _}, {deliver, ?VA, #{context := error}}], E2),
    ?assertMatch(#{pending := 0}, evatar_pairing_logic:stats(St2)).

%% ---------------------------------------------------------------------------
%% Changes of registration
%% ---------------------------------------------------------------------------

redescription_rebinds_and_voids_requests_test() ->
    {St1, _} = h({signal, ?VA, signal(<<"r1">>, request, ?EMU, ?LIGHT)}, bound()),
    {St2, E2} = h({describe, ?AV, avatar_description([thermo])}, St1),
    ?assertEqual(ok, reply(E2)),
    %% The provider's entity is still there: it is told the request is void.
    [{?VA, Gone}, {?AV, Closed}] = delivered(E2),
    ?assertMatch(#{context := event, in_reply_to := <<"r1">>, receiver := ?LIGHT,
                   body := #{type := <<"RequestClosed">>,
                             parameters := [{<<"Reason">>, <<"Unbound">>}, _]}}, Closed),
    ?assertMatch(#{context := feedback, in_reply_to := <<"r1">>,
                   body := #{category := <<"EVATAR">>, type := <<"ProviderGone">>}}, Gone),
    ?assert(lists:member({cancel_timer, {feedback, ?EMU, <<"r1">>}}, E2)),
    [{?VA, #{bound := Bound, unbound := [Unbound]}}, {?AV, _}] = reports(E2),
    ?assertEqual(1, length(Bound)),
    ?assertMatch(#{consumer := #{component := ?EMU}, reason := no_provider}, Unbound),
    ?assertMatch(#{pending := 0, provider_gone := 1, rebinds := 3},
                 evatar_pairing_logic:stats(St2)),
    %% The component left, so is any route to it.
    {_, E3} = h({signal, ?VA, signal(<<"r2">>, request, ?EMU, ?LIGHT)}, St2),
    ?assertMatch([{deliver, ?VA, #{body := #{type := <<"UnknownReceiver">>}}}], no_logs(E3)).

%% Voiding many open requests: each gets its cancel_timer, its ProviderGone
%% and its log, in request key order, exactly once (it used to append per
%% request, quadratic).
voiding_many_requests_test() ->
    Ids = [<<"r", (integer_to_binary(I))/binary>> || I <- lists:seq(1, 3000)],
    St1 = lists:foldl(fun(Id, St) ->
                              {St1, _} = h({signal, ?VA, signal(Id, request, ?EMU, ?LIGHT)}, St),
                              St1
                      end, bound(#{max_open_requests => 3000}), Ids),
    ?assertMatch(#{pending := 3000}, evatar_pairing_logic:stats(St1)),
    {St2, E2} = h({describe, ?AV, avatar_description([thermo])}, St1),
    Sorted = lists:sort(Ids),
    ?assertEqual(Sorted, [R || {?VA, #{in_reply_to := R,
                                       body := #{type := <<"ProviderGone">>}}} <- delivered(E2)]),
    ?assertEqual(Sorted, [R || {cancel_timer, {feedback, ?EMU, R}} <- E2]),
    ?assertMatch(#{pending := 0, provider_gone := 3000}, evatar_pairing_logic:stats(St2)).

redescription_keeps_surviving_requests_test() ->
    {St1, _} = h({signal, ?VA, signal(<<"r1">>, request, ?EMU, ?LIGHT)}, bound()),
    {St2, E2} = h({describe, ?AV, avatar_description([light])}, St1),
    ?assertEqual([], delivered(E2)),
    ?assertMatch(#{pending := 1}, evatar_pairing_logic:stats(St2)).

avatar_leaving_unbinds_test() ->
    {St1, _} = h({signal, ?VA, signal(<<"r1">>, request, ?EMU, ?LIGHT)}, bound()),
    {St2, E2} = h({leave, ?AV, down}, St1),
    ?assertEqual(ok, reply(E2)),
    [{?VA, #{body := #{type := <<"ProviderGone">>}}}] = delivered(E2),
    ?assertEqual([{?VA, #{bound => [], unbound => maps:get(unbound, evatar_pairing_logic:bindings(St2)),
                          entities => [?VA]}}], reports(E2)),
    ?assertEqual(waiting, evatar_pairing_logic:phase(St2)),
    ?assertEqual([?VA], evatar_pairing_logic:entity_ids(St2)).

agent_leaving_keeps_the_pairing_for_a_new_agent_test() ->
    {St1, _} = h({signal, ?VA, signal(<<"r1">>, request, ?EMU, ?LIGHT)}, bound()),
    {St2, E2} = h({leave, ?VA, left}, St1),
    %% The requester is gone: its request is closed, and its provider told.
    ?assert(lists:member({cancel_timer, {feedback, ?EMU, <<"r1">>}}, E2)),
    ?assertMatch([{?AV, #{context := event, in_reply_to := <<"r1">>,
                          body := #{type := <<"RequestClosed">>,
                                    parameters := [{<<"Reason">>, <<"RequesterGone">>}, _]}}}],
                 delivered(E2)),
    ?assertMatch([{?AV, #{entities := [?AV]}}], reports(E2)),
    ?assertMatch(#{pending := 0}, evatar_pairing_logic:stats(St2)),
    St3 = ok({join, agent, <<"va2">>, <<"agent-secret">>}, St2),
    Va2 = (agent_description())#{entity_id => <<"va2">>},
    {St4, _} = h({describe, <<"va2">>, Va2}, St3),
    ?assertEqual(bound, evatar_pairing_logic:phase(St4)).

leaving_before_registering_cancels_the_join_timer_test() ->
    {_, Effects} = h({leave, ?AV, left}, joined()),
    ?assertEqual([{reply, ok}, {cancel_timer, {join, ?AV}}], no_logs(Effects)).

leaving_twice_is_harmless_test() ->
    {St, _} = h({leave, ?AV, left}, bound()),
    ?assertEqual({St, [{reply, ok}]}, h({leave, ?AV, left}, St)).

%% A GetBinding: the current report to that entity alone, no state change.
report_binding_test() ->
    St = bound(),
    ?assertEqual({St, [{report, ?VA, evatar_pairing_logic:bindings(St)}]},
                 h({report_binding, ?VA}, St)),
    ?assertEqual({St, []}, h({report_binding, <<"ghost">>}, St)),
    %% Joined, not described yet: it is told too (Entities lists the others).
    St1 = ok({join, avatar, <<"7009">>, <<"avatar-secret">>}, St),
    ?assertMatch({_, [{report, <<"7009">>, #{entities := [?VA, ?AV]}}]},
                 h({report_binding, <<"7009">>}, St1)).

%% A Progress answering no open request is refused like a late Feedback.
progress_without_request_is_refused_test() ->
    {_, E} = h({signal, ?AV, signal(<<"p">>, progress, ?LIGHT, ?EMU, <<"never">>)}, bound()),
    ?assertMatch([{deliver, ?AV, #{in_reply_to := <<"p">>,
                                   body := #{type := <<"NoOpenRequest">>}}}], no_logs(E)).

%% Signals go either way along a binding row: the provider may send
%% SensorData, an Event or a request to its consumer (section 4.2).
either_direction_along_a_binding_test() ->
    {St1, E1} = h({signal, ?AV, signal(<<"s">>, sensor_data, ?LIGHT, ?EMU)}, bound()),
    ?assertMatch([{deliver, ?VA, #{id := <<"s">>}}], no_logs(E1)),
    {St2, E2} = h({signal, ?AV, signal(<<"q">>, request, ?LIGHT, ?EMU)}, St1),
    ?assertMatch([{deliver, ?VA, #{id := <<"q">>}}, {start_timer, {feedback, ?LIGHT, <<"q">>}, _}],
                 no_logs(E2)),
    {_, E3} = h({signal, ?VA, signal(<<"a">>, feedback, ?EMU, ?LIGHT, <<"q">>)}, St2),
    ?assertMatch([{cancel_timer, _}, {deliver, ?AV, #{id := <<"a">>}}], no_logs(E3)).

registration_order_survives_redescription_test() ->
    St = ok({describe, ?VA, agent_description()}, bound()),
    ?assertMatch(#{entities := [?VA, ?AV]}, evatar_pairing_logic:bindings(St)).

timers_for_takeover_test() ->
    St1 = ok({describe, ?VA, agent_description()}, joined()),
    ?assertEqual([{{join, ?AV}, 60}], evatar_pairing_logic:timers(St1, 1040)),
    {St2, _} = h({signal, ?VA, signal(<<"r1">>, request, ?EMU, ?LIGHT)}, bound()),
    ?assertEqual([{{feedback, ?EMU, <<"r1">>}, 0}], evatar_pairing_logic:timers(St2, 5000)).

summary_test() ->
    ?assertMatch(#{state := bound, agent := ?VA, avatars := 1, registered := 2, bound := 3,
                   unbound := 0, pending := 0, epoch := 1},
                 evatar_pairing_logic:summary(bound())).
