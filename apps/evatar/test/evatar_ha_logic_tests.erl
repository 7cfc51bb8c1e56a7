%% @doc EUnit tests of what high availability adds to the pure pairing logic
%% (de-duplication window, outbound buffer, resume, detach, takeover,
%% SlowConsumer) and of the pure decisions in evatar_ha_membership and evatar_ha_core.
-module(evatar_ha_logic_tests).

-include_lib("eunit/include/eunit.hrl").

-define(P, <<"home">>).
-define(VA, <<"va1">>).
-define(AV, <<"av1">>).
-define(EMU, <<"Emu">>).
-define(LIGHT, <<"Light">>).
-define(CA, <<"ca">>).
-define(CV, <<"cv">>).

%% ---------------------------------------------------------------------------
%% Fixtures
%% ---------------------------------------------------------------------------

config(Extra) ->
    {ok, C} = evatar_pairing_logic:config(
                maps:merge(#{agent_credential => ?CA, avatar_credential => ?CV,
                             join_timeout => 100, feedback_timeout => 200,
                             resume_timeout => 500, dedup_window => 3,
                             max_unacked_out => 4}, Extra)),
    C.

entry(Cat, Type) -> #{category => Cat, type => Type, parameters => []}.

va() ->
    #{entity_id => ?VA, api_name => <<"VA">>, entity_type => agent, context => <<>>,
      components => [#{id => ?EMU, services => [entry(<<"A">>, <<"Feedback">>)],
                       consumes => [entry(<<"A">>, <<"On">>)]}]}.

av() ->
    #{entity_id => ?AV, api_name => <<"AV">>, entity_type => avatar, context => <<>>,
      components => [#{id => ?LIGHT, services => [entry(<<"A">>, <<"On">>)], consumes => []}]}.

light(Id) ->
    #{id => Id, context => request_no_feedback, sender => ?EMU, receiver => ?LIGHT,
      in_reply_to => undefined, timestamp => 1, seq => undefined, epoch => undefined,
      body => entry(<<"A">>, <<"On">>)}.

h(Event, St) -> evatar_pairing_logic:handle(Event, 1000, St).

run(Events, St) -> lists:foldl(fun(E, S) -> element(1, h(E, S)) end, St, Events).

%% Both entities joined with sessions (protocol version 2) and bound.
bound() -> bound(#{}).

bound(Extra) ->
    St = evatar_pairing_logic:new(?P, config(Extra)),
    run([{join, agent, ?VA, ?CA, <<"sa">>}, {join, avatar, ?AV, ?CV, <<"sv">>},
         {describe, ?VA, va()}, {describe, ?AV, av()}], St).

delivered(Effects) -> [{E, Id, Seq} || {deliver, E, #{id := Id, seq := Seq}} <- Effects].

accepted(Effects) -> [{E, Id} || {accepted, E, Id} <- Effects].

reply(Effects) -> [R || {reply, R} <- Effects].

%% ---------------------------------------------------------------------------
%% De-duplication
%% ---------------------------------------------------------------------------

%% An accepted signal resent (a lost Ack) is acknowledged again, not routed.
resent_signal_is_acknowledged_not_routed_test() ->
    {St1, E1} = h({signal, ?VA, light(<<"s1">>)}, bound()),
    ?assertEqual([{?AV, <<"s1">>, 1}], delivered(E1)),
    ?assertEqual([{?VA, <<"s1">>}], accepted(E1)),
    {St2, E2} = h({signal, ?VA, light(<<"s1">>)}, St1),
    ?assertEqual([], delivered(E2)),
    ?assertEqual([{?VA, <<"s1">>}], accepted(E2)),
    ?assertMatch(#{duplicates := 1}, evatar_pairing_logic:stats(St2)),
    ?assertEqual(<<"s1">>, evatar_pairing_logic:last_accepted(St2, ?VA)).

%% The window is bounded: beyond dedup_window newer ids the oldest is
%% forgotten (hence the client's obligation to keep fewer unacknowledged).
window_is_bounded_test() ->
    St = run([{signal, ?VA, light(I)} || I <- [<<"1">>, <<"2">>, <<"3">>, <<"4">>]], bound()),
    {_, E1} = h({signal, ?VA, light(<<"1">>)}, St),
    ?assertMatch([{?AV, <<"1">>, _}], delivered(E1)),
    {_, E4} = h({signal, ?VA, light(<<"4">>)}, St),
    ?assertEqual([], delivered(E4)).

%% A refused signal is accepted too (the refusal is the outcome), once.
refusal_is_accepted_once_test() ->
    Bad = (light(<<"x">>))#{receiver => <<"Nobody">>},
    {St1, E1} = h({signal, ?VA, Bad}, bound()),
    ?assertMatch([{deliver, ?VA, #{context := error}} | _], E1),
    ?assertEqual([{?VA, <<"x">>}], accepted(E1)),
    {_, E2} = h({signal, ?VA, Bad}, St1),
    ?assertEqual([{?VA, <<"x">>}], accepted(E2)),
    ?assertEqual([], [D || {deliver, _, _} = D <- E2]).

%% Protocol version 1 entities get none of this.
version_1_entities_have_no_acks_test() ->
    St = run([{join, agent, ?VA, ?CA}, {join, avatar, ?AV, ?CV}, {describe, ?VA, va()},
              {describe, ?AV, av()}], evatar_pairing_logic:new(?P, config(#{}))),
    {St1, E1} = h({signal, ?VA, light(<<"s1">>)}, St),
    ?assertEqual([], accepted(E1)),
    {_, E2} = h({signal, ?VA, light(<<"s1">>)}, St1),
    ?assertMatch([{?AV, <<"s1">>, 2}], delivered(E2)).

%% ---------------------------------------------------------------------------
%% Outbound buffer and resume
%% ---------------------------------------------------------------------------

%% What was delivered and not acknowledged is delivered again on resume,
%% with the current epoch; acknowledged signals are not.
resume_redelivers_unacknowledged_test() ->
    St = run([{signal, ?VA, light(I)} || I <- [<<"a">>, <<"b">>, <<"c">>]], bound()),
    St1 = run([{client_ack, ?AV, 1}, {detach, ?AV}, {takeover, 2}], St),
    {St2, E} = h({resume, avatar, ?AV, ?CV, <<"sv">>, 1, 1}, St1),
    ?assertEqual([{ok, true, <<>>}], reply(E)),
    ?assertEqual([{?AV, <<"b">>, 2}, {?AV, <<"c">>, 3}], delivered(E)),
    %% The current Binding report comes first (docs/protocol.md 11.2).
    [{report, ?AV, Report} | _] = [X || X <- E, element(1, X) =:= report orelse
                                           element(1, X) =:= deliver],
    ?assertEqual(evatar_pairing_logic:bindings(St2), Report),
    ?assertEqual([2, 2], [Ep || {deliver, _, #{epoch := Ep}} <- E]).

%% The resume's Received also trims: nothing at or below it comes again.
resume_trims_by_received_test() ->
    St = run([{signal, ?VA, light(I)} || I <- [<<"a">>, <<"b">>]], bound()),
    {_, E} = h({resume, avatar, ?AV, ?CV, <<"sv">>, 2, 1}, St),
    ?assertEqual([], delivered(E)).

%% A client that saw Sequence numbers this history does not have (two-node
%% partition) never sees them reused for other signals.
resume_beyond_history_advances_sequence_test() ->
    {St, _} = h({resume, avatar, ?AV, ?CV, <<"sv">>, 7, 1}, bound()),
    {_, E} = h({signal, ?VA, light(<<"n">>)}, St),
    ?assertEqual([{?AV, <<"n">>, 8}], delivered(E)).

%% A client that has seen a newer epoch than this instance is refused.
resume_with_newer_epoch_is_refused_test() ->
    {_, E} = h({resume, avatar, ?AV, ?CV, <<"sv">>, 0, 5}, bound()),
    ?assertEqual([{error, stale_epoch}], reply(E)).

%% An unknown session is a fresh join, and says so.
resume_of_unknown_session_is_a_fresh_join_test() ->
    St = evatar_pairing_logic:new(?P, config(#{})),
    {St1, E} = h({resume, avatar, ?AV, ?CV, <<"gone">>, 3, 9}, St),
    ?assertEqual([{ok, false, <<>>}], reply(E)),
    ?assertEqual([?AV], evatar_pairing_logic:entity_ids(St1)).

%% A session that joined but whose description never arrived (the
%% connection carrying it was lost, nemesis_SUITE in CI) is not resumed:
%% with `Resumed' true the client would never describe itself again, and
%% every signal it sent would be refused NotDescribed until the join
%% timeout. It starts afresh and is asked for its description.
resume_of_undescribed_session_starts_afresh_test() ->
    St = evatar_pairing_logic:new(?P, config(#{})),
    {St1, _} = h({resume, avatar, ?AV, ?CV, <<"sv">>, 0, 1}, St),
    St2 = run([{detach, ?AV}], St1),
    {St3, E} = h({resume, avatar, ?AV, ?CV, <<"sv">>, 0, 1}, St2),
    ?assertEqual([{ok, false, <<>>}], reply(E)),
    ?assertEqual([?AV], evatar_pairing_logic:entity_ids(St3)),
    %% Described now, it is served.
    {St4, _} = h({describe, ?AV, av()}, St3),
    {_, E2} = h({resume, avatar, ?AV, ?CV, <<"sv">>, 0, 1}, run([{detach, ?AV}], St4)),
    ?assertEqual([{ok, true, <<>>}], reply(E2)).

%% A wrong credential is refused before anything else is looked at.
resume_with_wrong_credential_test() ->
    {_, E} = h({resume, avatar, ?AV, <<"nope">>, <<"sv">>, 0, 1}, bound()),
    ?assertEqual([{error, bad_credential}], reply(E)).

%% Too many unacknowledged deliveries: the entity is dropped (SlowConsumer).
unacknowledged_overflow_drops_test() ->
    St = run([{signal, ?VA, light(integer_to_binary(I))} || I <- lists:seq(1, 4)], bound()),
    {St1, E} = h({signal, ?VA, light(<<"5">>)}, St),
    ?assertMatch([{drop, ?AV, slow_consumer, _}], [D || {drop, _, _, _} = D <- E]),
    ?assertEqual([?VA], evatar_pairing_logic:entity_ids(St1)),
    ?assertEqual([{?VA, <<"5">>}], accepted(E)).

%% The silent-link check sees the oldest unacknowledged delivery per entity.
unacked_since_test() ->
    {St, _} = evatar_pairing_logic:handle({signal, ?VA, light(<<"a">>)}, 4242, bound()),
    ?assertEqual([{?AV, 4242}], evatar_pairing_logic:unacked_since(St)),
    ?assertEqual([], evatar_pairing_logic:unacked_since(run([{client_ack, ?AV, 1}], St))).

%% ---------------------------------------------------------------------------
%% Detach, takeover, replacement
%% ---------------------------------------------------------------------------

%% A session entity whose connection went is kept for resume_timeout, then
%% leaves; a version 1 entity leaves at once.
detach_keeps_then_leaves_test() ->
    {St1, E1} = h({detach, ?AV}, bound()),
    ?assertEqual([{start_timer, {resume, ?AV}, 500}], [T || {start_timer, _, _} = T <- E1]),
    ?assertEqual([?AV, ?VA], evatar_pairing_logic:entity_ids(St1)),
    ?assertEqual([?VA], evatar_pairing_logic:attached_ids(St1)),
    {St2, E2} = h({timeout, {resume, ?AV}}, St1),
    ?assertEqual([?VA], evatar_pairing_logic:entity_ids(St2)),
    ?assertMatch([_ | _], [R || {report, ?VA, _} = R <- E2]),
    St3 = run([{join, agent, <<"va2">>, ?CA}], evatar_pairing_logic:new(?P, config(#{}))),
    {St4, _} = h({detach, <<"va2">>}, St3),
    ?assertEqual([], evatar_pairing_logic:entity_ids(St4)).

%% A takeover raises the epoch, detaches everybody and arms their resume
%% timers (timers/2 lists them for the process).
takeover_test() ->
    {St, E} = h({takeover, 2}, bound()),
    ?assertEqual(2, evatar_pairing_logic:epoch(St)),
    ?assertEqual([], evatar_pairing_logic:attached_ids(St)),
    ?assertEqual(lists:sort([{start_timer, {resume, ?AV}, 500}, {start_timer, {resume, ?VA}, 500}]),
                 lists:sort([T || {start_timer, _, _} = T <- E])),
    ?assertEqual([{{resume, ?AV}, 400}, {{resume, ?VA}, 400}],
                 lists:sort(evatar_pairing_logic:timers(St, 1100))).

%% An active re-elected while serving moves its epoch and keeps every
%% entity attached, with no timer armed: its clients are still connected.
reelected_test() ->
    Bound = bound(),
    Attached = evatar_pairing_logic:attached_ids(Bound),
    {St, E} = h({reelected, 3}, Bound),
    ?assertEqual(3, evatar_pairing_logic:epoch(St)),
    ?assertEqual(Attached, evatar_pairing_logic:attached_ids(St)),
    ?assertEqual([], [T || {start_timer, _, _} = T <- E]),
    ?assertEqual([{log, notice, #{what => reelected, epoch => 3}}], E).

%% A fresh join of a detached entity's id replaces it (the client came back
%% without resuming); an attached one is still refused.
fresh_join_replaces_detached_test() ->
    {_, E1} = h({join, avatar, ?AV, ?CV, <<"new">>}, bound()),
    ?assertEqual([{error, entity_exists}], reply(E1)),
    St = run([{detach, ?AV}], bound()),
    {St1, E2} = h({join, avatar, ?AV, ?CV, <<"new">>}, St),
    ?assertEqual([ok], reply(E2)),
    ?assertEqual([?VA], evatar_pairing_logic:attached_ids(St1) -- [?AV]),
    %% The new session is the one a Resume continues, once described.
    {St2, _} = h({describe, ?AV, av()}, St1),
    {_, E3} = h({resume, avatar, ?AV, ?CV, <<"new">>, 0, 1}, St2),
    ?assertEqual([{ok, true, <<>>}], reply(E3)).

%% The same events at the same times give the same state: what replication
%% by event shipping rests on.
deterministic_test() ->
    Events = [{signal, ?VA, light(<<"a">>)}, {client_ack, ?AV, 1}, {detach, ?VA},
              {resume, agent, ?VA, ?CA, <<"sa">>, 0, 1}, {signal, ?VA, light(<<"a">>)},
              {takeover, 2}],
    Start = bound(),
    ?assertEqual(run(Events, Start), run(Events, Start)).

%% ---------------------------------------------------------------------------
%% evatar_ha_membership and evatar_ha_core (votes, registrations, fencing, reconcile)
%% ---------------------------------------------------------------------------

standby_node_test_() ->
    Ring = [a@h, b@h, c@h],
    [?_assertEqual(b@h, evatar_ha_membership:standby_node(Ring, a@h, Ring, undefined)),
     ?_assertEqual(a@h, evatar_ha_membership:standby_node(Ring, c@h, Ring, undefined)),
     ?_assertEqual(c@h, evatar_ha_membership:standby_node(Ring, a@h, [a@h, c@h], undefined)),
     ?_assertEqual(c@h, evatar_ha_membership:standby_node(Ring, a@h, Ring, c@h)),
     ?_assertEqual(b@h, evatar_ha_membership:standby_node(Ring, a@h, Ring, x@h)),
     ?_assertEqual(none, evatar_ha_membership:standby_node(Ring, a@h, [a@h], undefined))].

majority_test_() ->
    [?_assert(evatar_ha_membership:majority([a, b, c], [a, b])),
     ?_assertNot(evatar_ha_membership:majority([a, b, c], [a])),
     ?_assertNot(evatar_ha_membership:majority([a, b, c, d], [a, b])),
     ?_assertNot(evatar_ha_membership:majority([a, b, c], [a, x, y]))].

fence_test_() ->
    [?_assertNot(evatar_ha_core:must_fence(2, false, false)),
     ?_assert(evatar_ha_core:must_fence(3, false, false)),
     ?_assertNot(evatar_ha_core:must_fence(3, false, true)),
     ?_assertNot(evatar_ha_core:must_fence(3, true, false))].

quorum_size_test_() ->
    [?_assertEqual(1, evatar_ha_core:quorum_size(1)),
     ?_assertEqual(1, evatar_ha_core:quorum_size(2)),
     ?_assertEqual(2, evatar_ha_core:quorum_size(3)),
     ?_assertEqual(3, evatar_ha_core:quorum_size(4)),
     ?_assertEqual(3, evatar_ha_core:quorum_size(5))].

%% Votes: the pids only name instances here.
votes_test_() ->
    A = list_to_pid("<0.101.0>"),
    B = list_to_pid("<0.102.0>"),
    S2 = list_to_pid("<0.103.0>"),
    New = evatar_ha_core:new_record(),
    {ok, HeldByA} = evatar_ha_core:register(New, 1, 1, A),
    {granted, ToB} = evatar_ha_core:vote(HeldByA, 2, B, {1, 1}, false),
    [%% While the holder is heard, nobody else gets the pairing.
     ?_assertEqual({refused, holder_live}, evatar_ha_core:vote(HeldByA, 2, B, {1, 1}, true)),
     %% One promise per epoch: epoch 2 went to B; C needs epoch 3.
     ?_assertEqual({refused, {promised, 2}}, evatar_ha_core:vote(ToB, 2, S2, {1, 1}, false)),
     ?_assertMatch({granted, _}, evatar_ha_core:vote(ToB, 2, B, {1, 1}, false)),
     ?_assertMatch({granted, #{promised := 3, holder := S2}},
                   evatar_ha_core:vote(ToB, 3, S2, {1, 1}, false)),
     %% A configuration made without B (A dropped it) makes B's claim stale
     %% for good, and one promised to B's epoch refuses A's registration.
     ?_assertEqual({refused, stale_claim},
                   evatar_ha_core:vote(element(2, evatar_ha_core:register(HeldByA, 1, 2, A)),
                                        2, B, {1, 1}, false)),
     ?_assertEqual({refused, {promised, 2}}, evatar_ha_core:register(ToB, 1, 2, A)),
     %% The winner's own configuration is accepted.
     ?_assertMatch({ok, #{promised := 2, holder := B, conf := {2, 1}}},
                   evatar_ha_core:register(ToB, 2, 1, B))].

%% A partial partition (A active, its standby B cut from A, C hearing both):
%% B's own node grants, C refuses while it hears A: one vote of three, so B
%% cannot win, and A's configuration without B is accepted by A and C.
partial_partition_votes_test() ->
    A = list_to_pid("<0.101.0>"),
    B = list_to_pid("<0.102.0>"),
    {ok, Rec} = evatar_ha_core:register(evatar_ha_core:new_record(), 1, 1, A),
    OnB = evatar_ha_core:vote(Rec, 2, B, {1, 1}, false),
    OnC = evatar_ha_core:vote(Rec, 2, B, {1, 1}, true),
    Granted = length([G || {granted, _} = G <- [OnB, OnC]]),
    ?assert(Granted < evatar_ha_core:quorum_size(3)),
    ?assertMatch({ok, _}, evatar_ha_core:register(Rec, 1, 2, A)),
    {granted, RecB} = OnB,
    ?assertMatch({refused, _}, evatar_ha_core:register(RecB, 1, 2, A)).

reconcile_test_() ->
    P1 = list_to_pid("<0.1.0>"),
    P2 = list_to_pid("<0.2.0>"),
    I = fun(Role, Epoch, Node, Pid) -> #{role => Role, epoch => Epoch, node => Node, pid => Pid} end,
    [?_assertEqual(step_down, evatar_ha_core:reconcile(I(active, 1, a, P1), I(active, 2, b, P2))),
     ?_assertEqual(keep, evatar_ha_core:reconcile(I(active, 2, a, P1), I(fenced, 1, b, P2))),
     ?_assertEqual(step_down, evatar_ha_core:reconcile(I(fenced, 2, b, P1), I(active, 2, a, P2))),
     ?_assertEqual(keep, evatar_ha_core:reconcile(I(active, 2, a, P1), I(active, 2, b, P2))),
     ?_assertEqual(stop, evatar_ha_core:reconcile((I(standby, 1, a, P1))#{peer => P1},
                                                    I(active, 2, b, P2))),
     ?_assertEqual(keep, evatar_ha_core:reconcile((I(standby, 1, a, P1))#{peer => P2},
                                                    I(active, 2, b, P2))),
     ?_assertEqual(keep, evatar_ha_core:reconcile(I(standby, 1, a, P1), I(standby, 2, b, P2)))].

stalled_test() ->
    ?assert(evatar_ha_membership:stalled(0, 1000, 250)),
    ?assertNot(evatar_ha_membership:stalled(0, 60, 250)).

%% A pause counts as a stall past lease + heartbeat (200 ms with the
%% release's 50/250/150): one that a peer whose clock runs up to 1 / 0.8
%% as fast measured as just over suspect_ms (250 ms) is noticed.
stall_ms_test() ->
    Stall = evatar_ha_membership:stall_ms(50, 150),
    ?assertEqual(200, Stall),
    ?assert(evatar_ha_membership:stalled(0, 216, Stall)),
    ?assertNot(evatar_ha_membership:stalled(0, 200, Stall)),
    ?assertEqual(ok, evatar_ha_membership:check_timings(#{heartbeat_ms => 50, suspect_ms => 250,
                                                          lease_ms => 150})),
    %% Never past suspect_ms: the timings that would put it there are refused.
    ?assertMatch({error, _}, evatar_ha_membership:check_timings(#{heartbeat_ms => 50,
                                                                 suspect_ms => 250,
                                                                 lease_ms => 250})).

%% A pause never fences by itself: a lone node keeps serving (nobody else
%% holds the state), a node of a cluster asks the others again, or awaits
%% the answer to a registration already under way.
after_pause_test_() ->
    [?_assertEqual(keep, evatar_ha_core:after_pause(1, false)),
     ?_assertEqual(keep, evatar_ha_core:after_pause(1, true)),
     ?_assertEqual(reconfirm, evatar_ha_core:after_pause(2, false)),
     ?_assertEqual(reconfirm, evatar_ha_core:after_pause(3, false)),
     ?_assertEqual(await, evatar_ha_core:after_pause(3, true)),
     ?_assertEqual(await, evatar_ha_core:after_pause(2, true))].

%% The timings of the defaults and of the release pass; a lease that would
%% outlive the others' suspicion, or a value that is no duration, is named.
check_timings_test_() ->
    T = fun(Hb, S, L) -> #{heartbeat_ms => Hb, suspect_ms => S, lease_ms => L} end,
    [?_assertEqual(ok, evatar_ha_membership:check_timings(T(50, 250, 150))),
     ?_assertEqual(ok, evatar_ha_membership:check_timings(T(100, 1000, 600))),
     ?_assertEqual(ok, evatar_ha_membership:check_timings(T(100, 250, 150))),
     ?_assertMatch({error, {bad_ha_timing, suspect_ms, 250, _}},
                   evatar_ha_membership:check_timings(T(101, 250, 150))),
     ?_assertMatch({error, {bad_ha_timing, heartbeat_ms, 0, _}},
                   evatar_ha_membership:check_timings(T(0, 250, 150))),
     ?_assertMatch({error, {bad_ha_timing, lease_ms, "150", _}},
                   evatar_ha_membership:check_timings(T(50, 250, "150")))].

%% A tick later than planned is this node's own pause; the peers' silence
%% is counted without it, and a peer silent before the pause stays silent.
own_pause_test_() ->
    [?_assertEqual(0, evatar_ha_membership:own_pause(1000, 1050, 50)),
     ?_assertEqual(0, evatar_ha_membership:own_pause(1000, 1030, 50)),
     ?_assertEqual(350, evatar_ha_membership:own_pause(1000, 1400, 50))].

discount_test_() ->
    Paused = evatar_ha_membership:own_pause(1000, 1400, 50),
    [%% Heard 40 ms before the last tick: 40 + 50 ms silent after the pause.
     ?_assertEqual(1310, evatar_ha_membership:discount(960, Paused, 1400)),
     ?_assert(1400 - evatar_ha_membership:discount(960, Paused, 1400) < 150),
     %% Silent for 300 ms before the pause: still silent for 300 + 50 ms.
     ?_assertEqual(1050, evatar_ha_membership:discount(700, Paused, 1400)),
     ?_assert(1400 - evatar_ha_membership:discount(700, Paused, 1400) > 250),
     %% Heard during the pause's last moments: never in the future.
     ?_assertEqual(1400, evatar_ha_membership:discount(1390, Paused, 1400)),
     ?_assertEqual(960, evatar_ha_membership:discount(960, 0, 1400))].

%% ---------------------------------------------------------------------------
%% A stale promise (issue 18): the active re-elects itself above it
%% ---------------------------------------------------------------------------

core_ctx(Role) ->
    #{nodes => [a, b, c], heartbeat_ms => 50, suspect_ms => 250, epoch => 1, role => Role}.

%% An active that lost its standby's node, its configuration {1, 1} not yet
%% registered.
lost_standby() ->
    {C, Effects} = evatar_ha_core:handle(standby_node_lost, core_ctx(active),
                                         evatar_ha_core:new()),
    ?assert(lists:member({timer, deadline, 500}, Effects)),
    {C1, _} = evatar_ha_core:handle({timeout, register}, core_ctx(active), C),
    C1.

%% Refused for a promise of epoch 2 (a standby cut off earlier): it asks
%% every node for epoch 3 with its own claim, still holding; a majority
%% re-elects it, it registers {3, 1} and is told so last; then releases.
reelect_above_stale_promise_test() ->
    C = lost_standby(),
    {C1, Votes} = evatar_ha_core:handle({register_reply, {1, 1}, b, {refused, {promised, 2}}},
                                        core_ctx(active), C),
    ?assertEqual([{vote, N, 3, {1, 1}, false} || N <- [a, b, c]],
                 [V || {vote, _, _, _, _} = V <- Votes]),
    ?assert(evatar_ha_core:holding(C1)),
    ?assert(evatar_ha_core:electing(C1)),
    %% The register retry waits for the election.
    ?assertEqual({C1, []}, evatar_ha_core:handle({timeout, register}, core_ctx(active), C1)),
    {C2, []} = evatar_ha_core:handle({vote_reply, 3, a, granted}, core_ctx(active), C1),
    {C3, Won} = evatar_ha_core:handle({vote_reply, 3, b, granted}, core_ctx(active), C2),
    ?assertEqual({won, reelect, 3}, lists:last(Won)),
    ?assertEqual([{register, N, {3, 1}} || N <- [a, b, c]],
                 [R || {register, _, _} = R <- Won]),
    ?assertEqual({3, 1}, evatar_ha_core:claim(C3)),
    ?assert(evatar_ha_core:holding(C3)),
    {C4, []} = evatar_ha_core:handle({register_reply, {3, 1}, a, ok}, core_ctx(active), C3),
    {C5, [registered]} = evatar_ha_core:handle({register_reply, {3, 1}, b, ok},
                                               core_ctx(active), C4),
    ?assertNot(evatar_ha_core:holding(C5)),
    %% The deadline of a registration that settled does nothing.
    ?assertEqual({C5, []}, evatar_ha_core:handle({timeout, deadline}, core_ctx(active), C5)).

%% An instance that really won the promised epoch and registered since
%% makes the re-election stale: the active is told it lost.
reelect_loses_to_a_newer_claim_test() ->
    {C1, _} = evatar_ha_core:handle({register_reply, {1, 1}, b, {refused, {promised, 2}}},
                                    core_ctx(active), lost_standby()),
    ?assertMatch({_, [{lost, stale_claim}]},
                 evatar_ha_core:handle({vote_reply, 3, b, {refused, stale_claim}},
                                       core_ctx(active), C1)).

%% After a pause a refusal for a promise means a standby may have won: no
%% re-election; refused by too many, the active fences.
no_reelect_after_pause_test() ->
    {C, _} = evatar_ha_core:handle(paused, core_ctx(active), evatar_ha_core:new()),
    {C1, []} = evatar_ha_core:handle({register_reply, {1, 0}, b, {refused, {promised, 2}}},
                                     core_ctx(active), C),
    ?assertNot(evatar_ha_core:electing(C1)),
    %% Still so after a retry of the registration.
    {C2, _} = evatar_ha_core:handle({timeout, register}, core_ctx(active), C1),
    {C3, []} = evatar_ha_core:handle({register_reply, {1, 0}, b, {refused, {promised, 2}}},
                                     core_ctx(active), C2),
    ?assertNot(evatar_ha_core:electing(C3)),
    ?assertMatch({_, [{fence, {promised, 2}}]},
                 evatar_ha_core:handle({register_reply, {1, 0}, c, {refused, {promised, 2}}},
                                       core_ctx(active), C3)).

%% Neither accepted nor refused in time (one refusal, one silent node, an
%% election that does not end): the active fences, saying why.
registration_deadline_fences_test() ->
    C = lost_standby(),
    ?assertMatch({_, [{fence, registration_timeout}]},
                 evatar_ha_core:handle({timeout, deadline}, core_ctx(active), C)),
    ?assertMatch({_, []}, evatar_ha_core:handle({timeout, deadline}, core_ctx(fenced), C)).
