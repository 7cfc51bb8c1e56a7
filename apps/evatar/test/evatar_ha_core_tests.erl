%% @doc Unit tests of the pure high-availability core: evatar_ha_core's
%% elections and registrations (event in, effects out) and evatar_ha_commit's
%% output commit. The leaf decisions (votes, registrations, fencing,
%% reconcile) are tested in evatar_ha_logic_tests.
-module(evatar_ha_core_tests).

-include_lib("eunit/include/eunit.hrl").

ctx(Role) ->
    #{nodes => [a, b, c], heartbeat_ms => 50, suspect_ms => 250, epoch => 1, role => Role}.

h(Event, Role, C) -> evatar_ha_core:handle(Event, ctx(Role), C).

%% A standby asks every node at the next epoch and arms one retry timer.
elect_test() ->
    {C, Effects} = h({elect, active_silent, false}, standby, evatar_ha_core:new()),
    ?assertEqual([{vote, a, 2, {1, 0}, false}, {vote, b, 2, {1, 0}, false},
                  {vote, c, 2, {1, 0}, false}, {timer, election, 10}], Effects),
    ?assert(evatar_ha_core:electing(C)),
    %% A second reason while one runs changes nothing.
    ?assertMatch({_, []}, h({elect, fenced, false}, standby, C)).

%% Two grants of three win: the new configuration {2, 1} is registered on
%% every node, effects are held, and `won' comes last.
won_test() ->
    {C1, _} = h({elect, active_silent, false}, standby, evatar_ha_core:new()),
    {C2, []} = h({vote_reply, 2, a, granted}, standby, C1),
    {C3, Effects} = h({vote_reply, 2, b, granted}, standby, C2),
    ?assertEqual({won, active_silent, 2}, lists:last(Effects)),
    ?assertEqual([a, b, c], [N || {register, N, {2, 1}} <- Effects]),
    ?assert(evatar_ha_core:holding(C3)),
    ?assertEqual({2, 1}, evatar_ha_core:claim(C3)),
    %% A majority of acceptances releases.
    {C4, []} = h({register_reply, {2, 1}, a, ok}, active, C3),
    {C5, [registered]} = h({register_reply, {2, 1}, b, ok}, active, C4),
    ?assertNot(evatar_ha_core:holding(C5)).

%% Refused for a promise to another candidate: again above it, soon.
promised_test() ->
    {C1, _} = h({elect, active_silent, false}, standby, evatar_ha_core:new()),
    {C2, [{timer, election, 5}]} = h({vote_reply, 2, a, {refused, {promised, 4}}}, standby, C1),
    {_, Effects} = h({timeout, election}, standby, C2),
    ?assertEqual([5], lists:usort([E || {vote, _, E, _, _} <- Effects])).

%% A stale claim loses for good.
stale_claim_test() ->
    {C1, _} = h({elect, active_silent, false}, standby, evatar_ha_core:new()),
    ?assertMatch({_, [{lost, stale_claim}]},
                 h({vote_reply, 2, a, {refused, stale_claim}}, standby, C1)).

%% Known dead after going silent: ask again at once with the lease waived.
dead_upgrades_a_running_election_test() ->
    {C1, _} = h({elect, active_silent, false}, standby, evatar_ha_core:new()),
    {_, Effects} = h({elect, {active_died, noproc}, true}, standby, C1),
    ?assertEqual([true], lists:usort([D || {vote, _, _, _, D} <- Effects])).

%% The standby's node lost: a new claim without it, registered a heartbeat
%% later, held meanwhile, with a deadline.
standby_node_lost_test() ->
    {C, Effects} = h(standby_node_lost, active, evatar_ha_core:new()),
    ?assertEqual([{timer, register, 50}, {timer, deadline, 500}], Effects),
    ?assert(evatar_ha_core:holding(C)),
    ?assertEqual({1, 1}, evatar_ha_core:claim(C)),
    {_, Sends} = h({timeout, register}, active, C),
    ?assertEqual([a, b, c], [N || {register, N, {1, 1}} <- Sends]).

%% The stale promise (issue 18): a node refuses the active's registration
%% for a promise to an instance that never served. The active stands for an
%% epoch above it while still holding, and on winning moves its own epoch
%% and registers it.
stale_promise_reelects_test() ->
    {C1, _} = h(standby_node_lost, active, evatar_ha_core:new()),
    {C2, _} = h({timeout, register}, active, C1),
    {C3, Votes} = h({register_reply, {1, 1}, b, {refused, {promised, 2}}}, active, C2),
    ?assertEqual([3], lists:usort([E || {vote, _, E, _, _} <- Votes])),
    ?assert(evatar_ha_core:holding(C3)),
    ?assert(evatar_ha_core:registering(C3)),  % takes no standby meanwhile
    {C4, []} = h({vote_reply, 3, a, granted}, active, C3),
    {C5, Regs} = h({vote_reply, 3, c, granted}, active, C4),
    ?assertEqual({won, reelect, 3}, lists:last(Regs)),
    ?assertEqual([a, b, c], [N || {register, N, {3, 1}} <- Regs]),
    ?assert(evatar_ha_core:holding(C5)).

%% Neither accepted nor refused in time: the active fences and says so.
deadline_fences_test() ->
    {C1, _} = h(standby_node_lost, active, evatar_ha_core:new()),
    ?assertMatch({_, [{fence, registration_timeout}]}, h({timeout, deadline}, active, C1)),
    ?assertMatch({_, []}, h({timeout, deadline}, fenced, C1)).

%% Refused by too many nodes (not for a promise): fence.
refused_fences_test() ->
    {C1, _} = h(standby_node_lost, active, evatar_ha_core:new()),
    {C2, _} = h({timeout, register}, active, C1),
    {C3, []} = h({register_reply, {1, 1}, a, {refused, stale_claim}}, active, C2),
    ?assertMatch({_, [{fence, stale_claim}]},
                 h({register_reply, {1, 1}, b, {refused, stale_claim}}, active, C3)).

%% After a pause: a lone node keeps going, a cluster reconfirms.
paused_test() ->
    Lone = #{nodes => [a], heartbeat_ms => 50, suspect_ms => 250, epoch => 1, role => active},
    ?assertMatch({_, [{pause, keep}]}, evatar_ha_core:handle(paused, Lone, evatar_ha_core:new())),
    {_, [{pause, reconfirm} | Rest]} = h(paused, active, evatar_ha_core:new()),
    ?assertEqual([a, b, c], [N || {register, N, {1, 0}} <- Rest]).

%% Only an instance that registered a configuration holds a lease: a
%% promise to a candidate that gave its election up blocks nobody.
blockers_test() ->
    {granted, Promised} = evatar_ha_core:vote(evatar_ha_core:new_record(), 2, b, {1, 1}, false),
    ?assertEqual([], evatar_ha_core:blockers(Promised, c, undefined, false)),
    {ok, Registered} = evatar_ha_core:register(Promised, 2, 1, b),
    ?assertEqual([b], evatar_ha_core:blockers(Registered, c, undefined, false)),
    ?assertEqual([a, b], evatar_ha_core:blockers(Registered, c, a, false)),
    ?assertEqual([b], evatar_ha_core:blockers(Registered, c, a, true)),
    ?assertEqual([], evatar_ha_core:blockers(Registered, b, undefined, false)).

%% A restore stands for election with restore votes, ignores a newer
%% claim a voter saw (its instances are gone), keeps one promise per epoch
%% and the lease of a holder heard, except on a node that said it runs
%% none; a node heard again that runs none is added, and asked again.
restore_test() ->
    {C1, Votes} = h({elect, {restore, [a]}, true}, fenced, evatar_ha_core:new()),
    ?assert(evatar_ha_core:restoring(C1)),
    ?assertEqual([a, b, c], [N || {restore_vote, N, 2, [a]} <- Votes]),
    {ok, Old} = evatar_ha_core:register(evatar_ha_core:new_record(), 5, 3, {b, 1}),
    ?assertEqual({refused, {promised, 5}}, evatar_ha_core:restore_vote(Old, 5, {a, 9}, false)),
    {granted, R} = evatar_ha_core:restore_vote(Old, 6, {a, 9}, false),
    ?assertEqual({5, 3}, maps:get(conf, R)),
    ?assertEqual({refused, holder_live}, evatar_ha_core:restore_vote(Old, 6, {a, 9}, true)),
    NodeOf = fun({N, _}) -> N end,
    ?assertEqual([{b, 1}], evatar_ha_core:restore_blockers(Old, {a, 9}, [a], NodeOf, undefined)),
    ?assertEqual([], evatar_ha_core:restore_blockers(Old, {a, 9}, [a, b], NodeOf, undefined)),
    ?assertEqual([{c, 2}], evatar_ha_core:restore_blockers(Old, {a, 9}, [b], NodeOf,
                                                           {{c, 2}, standby})),
    ?assertEqual([], evatar_ha_core:restore_blockers(Old, {a, 9}, [b], NodeOf, {{c, 2}, fenced})),
    {C2, Again} = h({runs_none, b}, fenced, C1),
    ?assertEqual([a, b, c], [N || {restore_vote, N, _, [a, b]} <- Again]),
    ?assertEqual({C2, []}, h({runs_none, b}, fenced, C2)).

%% ---------------------------------------------------------------------------
%% evatar_ha_commit
%% ---------------------------------------------------------------------------

-define(SIG, {deliver, <<"r">>, sig}).

%% Direct: everything now, Acks batched for the flush.
direct_test() ->
    {ok, Out, C} = evatar_ha_commit:step(ev, 0, [?SIG, {accepted, <<"s">>, <<"1">>}],
                                         #{}, direct, evatar_ha_commit:new(0)),
    ?assertEqual([?SIG], Out),
    ?assertEqual(1, evatar_ha_commit:version(C)),
    ?assertMatch({[{acks, #{<<"s">> := <<"1">>}}], _}, evatar_ha_commit:flush(direct, C)).

%% Replicated: timers and logs now; deliveries bound to their connection
%% and held until the standby confirms; the event shipped by the flush.
replicated_test() ->
    Effects = [{start_timer, k, 5}, ?SIG, {accepted, <<"s">>, <<"1">>}, {reply, r}],
    {r, Out, C1} = evatar_ha_commit:step(ev, 7, Effects, #{<<"r">> => conn}, replicated,
                                         evatar_ha_commit:new(0)),
    ?assertEqual([{start_timer, k, 5}], Out),
    ?assertMatch({[{ship, [{1, 7, ev}]}], _}, evatar_ha_commit:flush(replicated, C1)),
    ?assertMatch({[], _}, evatar_ha_commit:confirm(0, C1)),
    {Released, C2} = evatar_ha_commit:confirm(1, C1),
    ?assertEqual([{send, conn, {signal, sig}}, {acks, #{<<"s">> => <<"1">>}}], Released),
    ?assert(evatar_ha_commit:synced(C2)),
    ?assert(evatar_ha_commit:outbox_empty(C2)).

%% Held (a registration under way): nothing shipped, all released at once.
held_test() ->
    {ok, [], C1} = evatar_ha_commit:step(ev, 0, [?SIG], #{<<"r">> => conn}, held,
                                         evatar_ha_commit:new(3)),
    ?assertMatch({[], _}, evatar_ha_commit:flush(held, C1)),
    {Out, C2} = evatar_ha_commit:release_all(C1),
    ?assertEqual([{send, conn, {signal, sig}}], Out),
    ?assertEqual(4, evatar_ha_commit:version(C2)).

%% A report that changes no state never overtakes a held one; a reply waits
%% for the version it answers.
ordering_test() ->
    {ok, [], C1} = evatar_ha_commit:step(ev, 0, [?SIG], #{<<"r">> => conn}, replicated,
                                         evatar_ha_commit:new(0)),
    {[], C2} = evatar_ha_commit:report([{send, conn, rep}], replicated, C1),
    {[], C3} = evatar_ha_commit:reply(from, ok, replicated, C2),
    {Out, _} = evatar_ha_commit:confirm(1, C3),
    ?assertEqual([{send, conn, {signal, sig}}, {send, conn, rep}, {reply_to, from, ok}], Out),
    ?assertMatch({[{send, conn, rep}], _},
                 evatar_ha_commit:report([{send, conn, rep}], direct, evatar_ha_commit:new(0))).

%% The flush waits for an empty mailbox, at most FLUSH_EVERY events.
flush_maybe_test() ->
    {ok, _, C1} = evatar_ha_commit:step(ev, 0, [{accepted, <<"s">>, <<"1">>}], #{}, direct,
                                        evatar_ha_commit:new(0)),
    ?assertMatch({[flush_later], _}, evatar_ha_commit:flush_maybe(3, direct, C1)),
    ?assertMatch({[{acks, _}], _}, evatar_ha_commit:flush_maybe(0, direct, C1)),
    ?assertMatch({[], _}, evatar_ha_commit:flush_maybe(0, direct, evatar_ha_commit:new(0))).
