%% @doc Common Test suite of the mediator through its public API, with real
%% processes as entities (`evatar_test_entity'): joining, binding, routing,
%% feedback, timeouts, re-registration, refusals, fault isolation between
%% pairings, inspection, and a PropEr state machine model of the lifecycle.
-module(evatar_pairing_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, groups/0, suite/0, init_per_suite/1, end_per_suite/1,
         init_per_testcase/2, end_per_testcase/2]).
-export([join_describe_bind_report/1, request_feedback_round_trip/1,
         sensor_stream_in_order/1, feedback_timeout/1, progress_then_feedback/1,
         reregister_rebinds/1, not_bound_and_bad_sender/1, join_timeout_drops/1,
         join_refusals/1, describe_refusals/1, pairing_management/1,
         delete_uncatalogued_instance/1,
         entity_crash_unregisters/1, agent_leaves_and_returns/1,
         crashed_pairing_is_isolated/1, crash_loop_gives_up/1, crash_loop_at_creation_gives_up/1,
         configured_pairings/1, inspection/1, lifecycle_model/1]).

-include_lib("evatar_test_kit/include/evatar_entities.hrl").
-import(evatar_test_wait, [until/1]).

-define(AGENT_CRED, <<"agent-secret">>).
-define(AVATAR_CRED, <<"avatar-secret">>).

suite() -> [{timetrap, {minutes, 3}}].

all() -> [{group, mediator}, {group, faults}, lifecycle_model].

groups() ->
    [{mediator, [], [join_describe_bind_report, request_feedback_round_trip,
                     sensor_stream_in_order, feedback_timeout, progress_then_feedback,
                     reregister_rebinds, not_bound_and_bad_sender, join_timeout_drops,
                     join_refusals, describe_refusals, pairing_management,
                     delete_uncatalogued_instance, entity_crash_unregisters, agent_leaves_and_returns,
                     configured_pairings, inspection]},
     {faults, [], [crashed_pairing_is_isolated, crash_loop_gives_up,
                   crash_loop_at_creation_gives_up]}].

init_per_suite(Config) ->
    %% Another suite may have left evatar running without this env.
    _ = application:stop(evatar),
    case application:load(evatar) of
        ok -> ok;
        {error, {already_loaded, evatar}} -> ok
    end,
    ok = application:set_env(evatar, pairings,
                             [#{id => <<"configured">>, agent_credential => <<"a">>,
                                avatar_credential => <<"b">>, join_timeout => 60000}]),
    {ok, _} = application:ensure_all_started(evatar),
    Config.

end_per_suite(_Config) ->
    ok = application:stop(evatar),
    ok = application:unset_env(evatar, pairings).

init_per_testcase(TC, Config) ->
    Id = atom_to_binary(TC),
    [{pairing, Id} | Config].

end_per_testcase(_TC, Config) ->
    _ = evatar:delete_pairing(?config(pairing, Config)),
    ok.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

opts(Extra) ->
    maps:merge(#{agent_credential => ?AGENT_CRED, avatar_credential => ?AVATAR_CRED,
                 join_timeout => 30000, feedback_timeout => 30000}, Extra).

va_description() ->
    ?E:description(?VA, [{?EMU, [{<<"ACTUATOR">>, <<"ActionFeedback">>}],
                          [{<<"ACTUATOR">>, <<"TurnLightOn">>}]},
                         {?SINK, [{<<"SENSOR">>, <<"Temperature">>}], []}]).

av_description() -> av_description([light, thermo]).

av_description(Parts) ->
    All = [{light, {?LIGHT, [{<<"ACTUATOR">>, <<"TurnLightOn">>}],
                    [{<<"ACTUATOR">>, <<"Action Feedback">>}]}},
           {thermo, {?THERMO, [{<<"SENSOR">>, <<"Status">>}],
                     [{<<"SENSOR">>, <<"temperature">>}]}}],
    ?E:description(?AV, [C || {K, C} <- All, lists:member(K, Parts)]).

%% A pairing with a VA and an avatar joined, registered and bound; the two
%% binding reports each already consumed.
bound_pairing(Config, Extra) ->
    Id = ?config(pairing, Config),
    {ok, _} = evatar:create_pairing(Id, opts(Extra)),
    {ok, Va, VaPid} = ?E:start(Id, agent, ?VA, ?AGENT_CRED),
    {ok, Av, AvPid} = ?E:start(Id, avatar, ?AV, ?AVATAR_CRED),
    ok = evatar:describe(Va, va_description()),
    #{bound := []} = ?E:recv(?VA, bound),
    ok = evatar:describe(Av, av_description()),
    #{bound := [_, _, _]} = ?E:recv(?VA, bound),
    #{bound := [_, _, _]} = ?E:recv(?AV, bound),
    #{id => Id, va => Va, av => Av, va_pid => VaPid, av_pid => AvPid}.

error_type(#{context := error, sender := <<"EVATAR">>,
             body := #{category := <<"ERROR">>, type := Type}}) -> Type.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% @doc A VA and an Avatar join and register; both get the binding report.
join_describe_bind_report(Config) ->
    Id = ?config(pairing, Config),
    {ok, Pid} = evatar:create_pairing(Id, opts(#{})),
    {ok, Va, _} = ?E:start(Id, agent, ?VA, ?AGENT_CRED),
    ?assertEqual(Pid, evatar:session_pid(Va)),
    {ok, Av, _} = ?E:start(Id, avatar, ?AV, ?AVATAR_CRED),
    ok = evatar:describe(Va, va_description()),
    #{bound := [], unbound := [_], entities := [?VA]} = ?E:recv(?VA, bound),
    ok = evatar:describe(Av, av_description()),
    Report = ?E:recv(?VA, bound),
    ?assertEqual(Report, ?E:recv(?AV, bound)),
    #{bound := Bound, unbound := [], entities := [?VA, ?AV]} = Report,
    ?assertEqual(lists:sort([{?EMU, ?LIGHT}, {?LIGHT, ?EMU}, {?THERMO, ?SINK}]),
                 lists:sort([{C, P} || #{consumer := #{component := C},
                                         provider := #{component := P}} <- Bound])),
    ?assertEqual({ok, Report}, evatar:bindings(Id)).

%% @doc A request reaches the avatar stamped with seq and epoch; its feedback
%% comes back to the VA and closes it.
request_feedback_round_trip(Config) ->
    #{va := Va, av := Av, id := Id} = bound_pairing(Config, #{}),
    ok = evatar:send(Va, ?E:signal(<<"r1">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r1">>, seq := 1, epoch := 1, sender := ?EMU} = ?E:recv(?AV, signal),
    ok = evatar:send(Av, ?E:signal(<<"f1">>, feedback, ?LIGHT, ?EMU, <<"r1">>)),
    #{id := <<"f1">>, in_reply_to := <<"r1">>, seq := 1} = ?E:recv(?VA, signal),
    {ok, #{pending := 0, routed := #{request := 1, feedback := 1}}} = evatar:stats(Id).

%% @doc Ten thousand sensor signals arrive in order, sequenced 1..10000.
sensor_stream_in_order(Config) ->
    #{av := Av, id := Id} = bound_pairing(Config, #{}),
    N = 10000,
    [ok = evatar:send(Av, ?E:signal(integer_to_binary(I), sensor_data, ?THERMO, ?SINK))
     || I <- lists:seq(1, N)],
    Got = [begin
               #{id := SigId, seq := Seq} = ?E:recv(?VA, signal),
               {binary_to_integer(SigId), Seq}
           end || _ <- lists:seq(1, N)],
    ?assertEqual([{I, I} || I <- lists:seq(1, N)], Got),
    {ok, #{routed := #{sensor_data := N}, pending := 0}} = evatar:stats(Id).

%% @doc An unanswered request yields a Timeout feedback to the requester
%% and an Event RequestClosed to the provider; a late answer is not
%% delivered: its sender gets NoOpenRequest, and it is counted.
feedback_timeout(Config) ->
    #{va := Va, av := Av, id := Id, va_pid := VaPid} =
        bound_pairing(Config, #{feedback_timeout => evatar_test_time:ms(50)}),
    ok = evatar:send(Va, ?E:signal(<<"r1">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r1">>} = ?E:recv(?AV, signal),
    #{context := feedback, in_reply_to := <<"r1">>, sender := <<"EVATAR">>,
      body := #{category := <<"EVATAR">>, type := <<"Timeout">>}} = ?E:recv(?VA, signal),
    #{context := event, in_reply_to := <<"r1">>, receiver := ?LIGHT,
      body := #{type := <<"RequestClosed">>}} = ?E:recv(?AV, signal),
    ok = evatar:send(Av, ?E:signal(<<"f1">>, feedback, ?LIGHT, ?EMU, <<"r1">>)),
    #{context := error, in_reply_to := <<"f1">>,
      body := #{type := <<"NoOpenRequest">>}} = ?E:recv(?AV, signal),
    {ok, #{timeouts := 1, late_feedback := 1, pending := 0}} = evatar:stats(Id),
    ?assertEqual([], ?E:flush([VaPid])).

%% @doc Coarse grain: progress keeps a request open for longer than the
%% feedback timeout (each progress restarts it), then the final feedback
%% closes it; no Timeout is ever sent. Three pauses of 1200 ms outlast the
%% 3000 ms timeout unless each progress moves the deadline. A Timeout is
%% the pairing's fault when it comes less than the timeout after the test
%% sent the answer before (the deadline is a full timeout after that answer
%% was handled, which is no earlier than it was sent); later, the test
%% itself was late (a stall of the loaded machine longer than the 1800 ms
%% left), and it starts again on a new pairing, at most three times.
progress_then_feedback(Config) ->
    ok = progress_then_feedback(?config(pairing, Config), 3).

progress_then_feedback(Id, Attempts) ->
    #{va := Va, av := Av, va_pid := VaPid, av_pid := AvPid} =
        bound_pairing([{pairing, Id}], #{feedback_timeout => 3000}),
    Sent = erlang:monotonic_time(millisecond),
    ok = evatar:send(Va, ?E:signal(<<"walk">>, request, ?EMU, ?LIGHT)),
    #{id := <<"walk">>} = ?E:recv(?AV, signal),
    Steps = [{1200, <<"p", (integer_to_binary(I))/binary>>, progress} || I <- [1, 2, 3]]
        ++ [{0, <<"done">>, feedback}],
    case answer_in_time(Av, Sent, Steps) of
        ok ->
            {ok, #{routed := #{progress := 3, feedback := 1}, pending := 0, timeouts := 0}} =
                evatar:stats(Id),
            evatar:delete_pairing(Id);
        late when Attempts > 1 ->
            ok = evatar:delete_pairing(Id),
            _ = ?E:flush([VaPid, AvPid]),
            progress_then_feedback(<<Id/binary, "-again">>, Attempts - 1)
    end.

answer_in_time(_Av, _PrevSent, []) ->
    ok;
answer_in_time(Av, PrevSent, [{Pause, SigId, Context} | Rest]) ->
    %% The pause is the case's subject: real time must pass the feedback
    %% timeout while the progress signals keep moving its deadline (the
    %% pure rule is evatar_pairing_logic_tests' progress_extends_the_deadline).
    timer:sleep(Pause),
    Sent = erlang:monotonic_time(millisecond),
    ok = evatar:send(Av, ?E:signal(SigId, Context, ?LIGHT, ?EMU, <<"walk">>)),
    case ?E:recv(?VA, signal) of
        #{id := SigId, context := Context, in_reply_to := <<"walk">>} ->
            answer_in_time(Av, Sent, Rest);
        #{context := feedback, body := #{type := <<"Timeout">>}} ->
            case erlang:monotonic_time(millisecond) - PrevSent of
                Waited when Waited >= 3000 -> late;
                Waited -> error({timed_out_ms_after_the_answer_before, Waited})
            end
    end.

%% @doc A new description rebinds; a request to a vanished component is
%% answered ProviderGone (its provider told RequestClosed) and the component
%% is no longer reachable.
reregister_rebinds(Config) ->
    #{va := Va, av := Av} = bound_pairing(Config, #{}),
    ok = evatar:send(Va, ?E:signal(<<"r1">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r1">>} = ?E:recv(?AV, signal),
    ok = evatar:describe(Av, av_description([thermo])),
    #{in_reply_to := <<"r1">>, body := #{type := <<"ProviderGone">>}} = ?E:recv(?VA, signal),
    #{in_reply_to := <<"r1">>, body := #{type := <<"RequestClosed">>,
                                         parameters := [{<<"Reason">>, <<"Unbound">>}, _]}} =
        ?E:recv(?AV, signal),
    #{bound := [_], unbound := [#{reason := no_provider}]} = ?E:recv(?VA, bound),
    #{bound := [_]} = ?E:recv(?AV, bound),
    ok = evatar:send(Va, ?E:signal(<<"r2">>, request, ?EMU, ?LIGHT)),
    <<"UnknownReceiver">> = error_type(?E:recv(?VA, signal)),
    ok = evatar:describe(Av, av_description()),
    #{bound := [_, _, _]} = ?E:recv(?VA, bound),
    ok = evatar:send(Va, ?E:signal(<<"r3">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r3">>} = ?E:recv(?AV, signal).

%% @doc Refused signals get one error signal to the sender, nothing else.
not_bound_and_bad_sender(Config) ->
    #{va := Va, av := Av, va_pid := VaPid, av_pid := AvPid} = bound_pairing(Config, #{}),
    ok = evatar:send(Av, ?E:signal(<<"s1">>, sensor_data, ?THERMO, ?EMU)),
    #{in_reply_to := <<"s1">>} = E1 = ?E:recv(?AV, signal),
    <<"NotBound">> = error_type(E1),
    ok = evatar:send(Va, ?E:signal(<<"s2">>, request, ?LIGHT, ?EMU)),
    <<"BadSender">> = error_type(?E:recv(?VA, signal)),
    ok = evatar:send(Va, ?E:signal(<<"s3">>, event, ?EMU, <<"Nobody">>)),
    <<"UnknownReceiver">> = error_type(?E:recv(?VA, signal)),
    ok = evatar:send(Va, #{junk => true}),
    <<"BadSignal">> = error_type(?E:recv(?VA, signal)),
    ?assertEqual([], ?E:flush([VaPid, AvPid])).

%% @doc An entity that does not describe itself in time gets an error
%% signal, then `dropped'; the pairing forgets it.
join_timeout_drops(Config) ->
    Id = ?config(pairing, Config),
    JoinTimeout = evatar_test_time:ms(50),
    {ok, _} = evatar:create_pairing(Id, opts(#{join_timeout => JoinTimeout})),
    {ok, Av, _} = ?E:start(Id, avatar, ?AV, ?AVATAR_CRED),
    #{join_timeout := JoinTimeout, entity := ?AV, role := avatar} = evatar:session_info(Av),
    #{context := error, receiver := ?AV,
      body := #{type := <<"JoinTimeout">>}} = ?E:recv(?AV, signal),
    {join_timeout, Reason} = ?E:recv(?AV, dropped),
    true = is_binary(Reason),
    {ok, []} = evatar:registry(Id),
    {ok, #{dropped := 1}} = evatar:stats(Id),
    {ok, _, _} = ?E:start(Id, avatar, ?AV, ?AVATAR_CRED).

%% @doc Each way a join is refused, with the pairing unaffected.
join_refusals(Config) ->
    Id = ?config(pairing, Config),
    {ok, _} = evatar:create_pairing(Id, opts(#{max_avatars => 1})),
    {error, unknown_pairing} = ?E:start(<<"no such pairing">>, agent, ?VA, ?AGENT_CRED),
    {error, bad_credential} = ?E:start(Id, agent, ?VA, ?AVATAR_CRED),
    {error, bad_credential} = ?E:start(Id, avatar, ?AV, <<>>),
    {ok, _, _} = ?E:start(Id, agent, ?VA, ?AGENT_CRED),
    {error, occupied} = ?E:start(Id, agent, <<"va2">>, ?AGENT_CRED),
    {error, entity_exists} = ?E:start(Id, avatar, ?VA, ?AVATAR_CRED),
    {ok, _, _} = ?E:start(Id, avatar, ?AV, ?AVATAR_CRED),
    {error, too_many_entities} = ?E:start(Id, avatar, <<"7009">>, ?AVATAR_CRED),
    {ok, Entries} = evatar:registry(Id),
    ?assertEqual(lists:sort([?VA, ?AV]), lists:sort([E || #{entity := E} <- Entries])).

%% @doc Descriptions that contradict the join, or steal a component, are
%% refused with a readable reason.
describe_refusals(Config) ->
    #{av := Av, va := Va} = bound_pairing(Config, #{}),
    {error, <<"EntityID", _/binary>>} = evatar:describe(Av, va_description()),
    {error, <<"EntityType", _/binary>>} =
        evatar:describe(Av, (av_description())#{entity_type => agent}),
    Stolen = ?E:description(?AV, [{?EMU, [{<<"A">>, <<"B">>}], []}]),
    {error, <<"ComponentID 'LightEmulator01' is already used by entity 'va1'">>} =
        evatar:describe(Av, Stolen),
    {error, <<"malformed description">>} = evatar:describe(Va, not_a_description),
    %% The registrations are unchanged: routing still works.
    ok = evatar:send(Va, ?E:signal(<<"r1">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r1">>} = ?E:recv(?AV, signal).

%% @doc Deleting a pairing through a node that runs an instance of it but
%% whose catalogue has not learned its creation yet (it took over from the
%% home node, which died before its write got here) records the deletion:
%% a tombstone, so the creation arriving later cannot bring it back
%% (ha_SUITE restart_with_changed_catalogue once failed so).
delete_uncatalogued_instance(Config) ->
    Id = ?config(pairing, Config),
    {ok, _} = evatar_pairings_sup:start_pairing(Id, opts(#{})),
    none = evatar_catalogue:lookup(Id),
    ok = evatar:delete_pairing(Id),
    ?assertMatch([{Id, _, deleted}], [E || {I, _, _} = E <- evatar_catalogue:entries(), I =:= Id]),
    undefined = evatar_registry:whereis_name(Id),
    {error, not_found} = evatar:delete_pairing(Id).

%% @doc Pairings are created and deleted at run time; deleting one tells
%% its entities and frees the id.
pairing_management(Config) ->
    Id = ?config(pairing, Config),
    {ok, Pid} = evatar:create_pairing(Id, opts(#{})),
    {error, already_exists} = evatar:create_pairing(Id, opts(#{})),
    {error, {bad_option, {missing, [avatar_credential]}}} =
        evatar:create_pairing(<<"x">>, #{agent_credential => <<"a">>}),
    {error, {bad_option, {feedback_timeout, soon}}} =
        evatar:create_pairing(<<"x">>, opts(#{feedback_timeout => soon})),
    {error, {bad_option, {id, x}}} = evatar:create_pairing(x, opts(#{})),
    {error, not_found} = evatar:delete_pairing(<<"x">>),
    {ok, Va, _} = ?E:start(Id, agent, ?VA, ?AGENT_CRED),
    Ref = erlang:monitor(process, evatar:session_pid(Va)),
    ok = evatar:delete_pairing(Id),
    {pairing_deleted, <<"the pairing was deleted">>} = ?E:recv(?VA, dropped),
    receive {'DOWN', Ref, process, Pid, normal} -> ok end,
    {error, not_found} = evatar:delete_pairing(Id),
    {error, not_found} = evatar:stats(Id),
    ?assertNot(lists:member(Id, [I || #{id := I} <- evatar:pairings()])),
    {ok, Pid2} = evatar:create_pairing(Id, opts(#{})),
    ?assertNotEqual(Pid, Pid2).

%% @doc An entity process that dies is unregistered: open requests to it are
%% voided and the others get a new binding report.
entity_crash_unregisters(Config) ->
    #{va := Va, av_pid := AvPid, id := Id} = bound_pairing(Config, #{}),
    ok = evatar:send(Va, ?E:signal(<<"r1">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r1">>} = ?E:recv(?AV, signal),
    ok = ?E:kill(AvPid),
    #{in_reply_to := <<"r1">>, body := #{type := <<"ProviderGone">>}} = ?E:recv(?VA, signal),
    #{bound := [], entities := [?VA]} = ?E:recv(?VA, bound),
    {ok, [#{entity := ?VA}]} = evatar:registry(Id),
    [#{state := waiting, avatars := 0}] = evatar_pairing_statem:summary(Id),
    {ok, #{pending := 0, provider_gone := 1}} = evatar:stats(Id).

%% @doc The agent leaving keeps the pairing, which binds again when a new
%% agent registers.
agent_leaves_and_returns(Config) ->
    #{va := Va, id := Id} = bound_pairing(Config, #{}),
    ok = evatar:leave(Va),
    #{bound := [], entities := [?AV]} = ?E:recv(?AV, bound),
    ok = evatar:leave(Va),
    {ok, Va2, _} = ?E:start(Id, agent, <<"va2">>, ?AGENT_CRED),
    ok = evatar:describe(Va2, (va_description())#{entity_id => <<"va2">>}),
    #{bound := [_, _, _], entities := [?AV, <<"va2">>]} = ?E:recv(?AV, bound),
    [#{state := bound, agent := <<"va2">>}] =
        evatar_pairing_statem:summary(Id).

%% @doc Pairings from the application environment exist after start-up.
configured_pairings(_Config) ->
    [#{state := waiting}] = evatar_pairing_statem:summary(<<"configured">>),
    {ok, _, Pid} = ?E:start(<<"configured">>, avatar, ?AV, <<"b">>),
    {error, bad_credential} = ?E:start(<<"configured">>, agent, ?VA, <<"b">>),
    ok = ?E:stop(Pid).

%% @doc The operator's inspection functions return and print the pairing's
%% data.
inspection(Config) ->
    #{va := Va, id := Id} = bound_pairing(Config, #{}),
    ok = evatar:send(Va, ?E:signal(<<"r1">>, request, ?EMU, ?LIGHT)),
    ok = evatar:send(Va, ?E:signal(<<"r2">>, request, ?EMU, <<"Nobody">>)),
    #{id := <<"r1">>} = ?E:recv(?AV, signal),
    [Summary] = evatar_pairing_statem:summary(Id),
    #{state := bound, agent := ?VA, avatars := 1, registered := 2, bound := 3,
      unbound := 0, pending := 1, pid := Pid} = Summary,
    Pid = evatar:session_pid(Va),
    {ok, #{bound := [_, _, _], unbound := []}} = evatar:bindings(Id),
    {ok, [#{entity := ?VA, role := agent, registered := true, description := _},
          #{entity := ?AV, role := avatar, registered := true}]} = evatar:registry(Id),
    {ok, #{routed := #{request := 1}, errors := #{<<"UnknownReceiver">> := 1},
           pending := 1, timeouts := 0, late_feedback := 0}} = evatar:stats(Id),
    {error, not_found} = evatar:bindings(<<"nope">>),
    {error, not_found} = evatar:registry(<<"nope">>),
    ct:capture_start(),
    ok = evatar:print_pairings(),
    ok = evatar:print_bindings(Id),
    ok = evatar:print_registry(Id),
    ok = evatar:print_stats(Id),
    ct:capture_stop(),
    Printed = lists:flatten(ct:capture_get()),
    ct:log("~ts", [Printed]),
    [true = string:find(Printed, Text) =/= nomatch
     || Text <- [binary_to_list(Id), "va1/LightEmulator01", "HomeLightActuator01",
                 "TurnLightOn", "routed request", "UnknownReceiver", "PENDING"]],
    {error, not_found} = evatar:print_stats(<<"nope">>).

%% @doc One pairing killed: its entities see it go, another pairing keeps
%% routing, and the killed one comes back empty and joinable.
crashed_pairing_is_isolated(Config) ->
    #{id := Id, va := VaA} = bound_pairing(Config, #{}),
    Other = <<Id/binary, "-other">>,
    #{va := VaB, av := AvB} = bound_pairing([{pairing, Other}], #{}),
    TopSup = whereis(evatar_sup),
    PidA = evatar:session_pid(VaA),
    PidB = evatar:session_pid(VaB),
    Ref = erlang:monitor(process, PidA),
    exit(PidA, kill),
    receive {'DOWN', Ref, process, PidA, killed} -> ok end,
    ok = evatar:send(VaB, ?E:signal(<<"r1">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r1">>} = ?E:recv(?AV, signal),
    ok = evatar:send(AvB, ?E:signal(<<"f1">>, feedback, ?LIGHT, ?EMU, <<"r1">>)),
    #{id := <<"f1">>} = ?E:recv(?VA, signal),
    NewA = wait_for_restart(Id, PidA),
    {ok, []} = evatar:registry(Id),
    {ok, Va2, _} = ?E:start(Id, agent, ?VA, ?AGENT_CRED),
    NewA = evatar:session_pid(Va2),
    PidB = evatar:session_pid(VaB),
    true = is_process_alive(PidB),
    TopSup = whereis(evatar_sup),
    ok = evatar:delete_pairing(Other).

%% @doc A pairing that keeps crashing is removed after its restart limit;
%% the other pairings and evatar_sup are untouched.
crash_loop_gives_up(Config) ->
    #{id := Id} = bound_pairing(Config, #{}),
    Other = <<Id/binary, "-other">>,
    {ok, OtherPid} = evatar:create_pairing(Other, opts(#{})),
    TopSup = whereis(evatar_sup),
    ok = crash_past_limit(Id),
    undefined = evatar_registry:whereis_name(Id),
    {error, unknown_pairing} = ?E:start(Id, agent, ?VA, ?AGENT_CRED),
    ?assertNot(lists:member(Id, [I || #{id := I} <- evatar:pairings()])),
    OtherPid = evatar_registry:whereis_name(Other),
    TopSup = whereis(evatar_sup),
    ok = evatar:delete_pairing(Other).

%% @doc A pairing that crashes past its restart limit at once after its
%% creation, before the catalogue looked at what runs (every 500 ms), gave
%% up too: the catalogue does not start it again. It did, at its next look,
%% when it had not seen the pairing active yet (crash_loop_gives_up failed
%% so, 1 run in 6 at load 18, its pairing back).
crash_loop_at_creation_gives_up(Config) ->
    Id = ?config(pairing, Config),
    {ok, _} = evatar:create_pairing(Id, opts(#{})),
    ok = crash_past_limit(Id),
    %% The catalogue's next look, fired now.
    ok = evatar:run_now(catalogue),
    undefined = evatar_registry:whereis_name(Id),
    {ok, _} = evatar_catalogue:lookup(Id).

%% Kills the pairing's process once more than its restart limit (2) allows
%% and returns once its supervisor, having given up, is gone from
%% evatar_pairings_sup (not by counting children: a tree that an earlier
%% case deleted may still be going).
crash_past_limit(Id) ->
    P1 = evatar_registry:whereis_name(Id),
    {dictionary, Dict} = erlang:process_info(P1, dictionary),
    [Sup | _] = proplists:get_value('$ancestors', Dict),
    Ref = erlang:monitor(process, Sup),
    exit(P1, kill),
    P2 = wait_for_restart(Id, P1),
    exit(P2, kill),
    P3 = wait_for_restart(Id, P2),
    exit(P3, kill),
    receive {'DOWN', Ref, process, Sup, _} -> ok end,
    until(fun() -> not lists:keymember(Sup, 2, supervisor:which_children(evatar_pairings_sup)) end).

wait_for_restart(Id, Old) ->
    ok = until(fun() ->
                       case evatar_registry:whereis_name(Id) of
                           undefined -> false;
                           Old -> false;
                           _ -> true
                       end
               end),
    evatar_registry:whereis_name(Id).


%% @doc PropEr state machine model of the lifecycle (join, describe, route,
%% leave, crash of an entity process) against the real pairing.
lifecycle_model(_Config) ->
    ok = evatar_test_proper:check(evatar_pairing_statem:prop_lifecycle(), 500).
