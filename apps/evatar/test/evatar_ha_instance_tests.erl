%% @doc Unit tests of evatar_ha_instance: the role machine rule by rule
%% (decide/3: each test feeds events and a view and asserts the decisions),
%% then handle/3, which carries them out with the rules and the commit and
%% returns only I/O. Instances are `{Node, N}' as in the model: A on node
%% a, B on b, C on c.
-module(evatar_ha_instance_tests).

-include_lib("eunit/include/eunit.hrl").

-define(A, {a, 1}).
-define(B, {b, 2}).
-define(C, {c, 3}).

view(M) ->
    maps:merge(#{nodes => [a, b, c], heartbeat_ms => 50, suspect_ms => 250, epoch => 1,
                 version => 0, confirmed => 0, synced => false, alive => [a, b, c],
                 majority => true, heard => [a, b, c], standby_opt => true,
                 client_ack_timeout => 5000, handover_on_silent_link => true}, M).

h(Event, S) -> h(Event, #{}, S).
h(Event, V, S) -> evatar_ha_instance:decide(Event, view(V), S).

%% The active on a, after a create.
active() ->
    {S, _} = h({start, create, none}, evatar_ha_instance:new(p, ?A, #{})),
    S.

%% The active on a with its standby B, synced at version 3.
active_with_standby() ->
    {S, _} = h({msg, {offer, ?B, 0}}, active()),
    S.

%% The standby on b of the active A.
standby() ->
    {S0, _} = h({start, {standby_for, ?A}, none}, evatar_ha_instance:new(p, ?B, #{})),
    {S, _} = h({msg, {snapshot, ?A, 1, 3, logic_state, {1, 1}}}, S0),
    S.

%% A majority of the nodes answers `Reply' to every vote or registration
%% an effect list asks for.
grant(Effects, S) ->
    lists:foldl(fun({vote, N, Ec, _, _, _}, {Acc, Es}) when N =/= c ->
                        {Acc1, Es1} = h({msg, {vote_reply, p, Ec, N, granted}}, Acc),
                        {Acc1, Es ++ Es1};
                   ({register, N, Claim}, {Acc, Es}) when N =/= c ->
                        {Acc1, Es1} = h({msg, {register_reply, p, Claim, N, ok}}, Acc),
                        {Acc1, Es ++ Es1};
                   (_, Acc) -> Acc
                end, {S, []}, Effects).

has(Pattern, Effects) -> lists:any(Pattern, Effects).

%% A new pairing is active at once: a fresh state, published, a standby
%% placed on the next alive node.
create_test() ->
    {S, Es} = h({start, create, none}, evatar_ha_instance:new(p, ?A, #{})),
    ?assertEqual(active, evatar_ha_instance:role(S)),
    ?assertMatch([new_logic, {log, info, #{what := pairing_started}}, serving | _], Es),
    ?assert(lists:member({timer, place, 0}, Es)),
    ?assertMatch({_, [{start_standby, b}, {timer, place, 1000}]}, h({timeout, place}, S)),
    %% No standby on a lone node, nor with the option off.
    ?assertMatch({_, []}, h({timeout, place}, #{alive => [a]}, S)),
    ?assertMatch({_, []}, h({timeout, place}, #{standby_opt => false}, S)),
    ?assertEqual(direct, evatar_ha_instance:mode(S)).

%% A standby started for an active offers itself, postpones anything else,
%% and becomes the standby on the snapshot (confirming its version).
standby_start_test() ->
    {S0, Es0} = h({start, {standby_for, ?A}, none}, evatar_ha_instance:new(p, ?B, #{})),
    ?assertMatch([{monitor, active, ?A}, {send, ?A, {offer, 0}}, {timer, offered, 3250}], Es0),
    ?assertEqual({S0, [postpone]}, h({cluster, {quorum, true}}, S0)),
    ?assertMatch({_, [{log, info, _}, {stop, no_snapshot}]}, h({timeout, offered}, S0)),
    ?assertMatch({_, [{log, info, _}, {stop, dismissed}]}, h({msg, {dismiss, ?A}}, S0)),
    {S1, Es1} = h({msg, {snapshot, ?A, 1, 3, st, {1, 1}}}, S0),
    ?assertEqual(standby, evatar_ha_instance:role(S1)),
    ?assertMatch([{install, 3, st}, {send, ?A, {confirm, 3}} | _], Es1),
    ?assert(lists:member(publish, Es1)),
    %% Never back to an older state.
    ?assertEqual({S1, []}, h({msg, {snapshot, ?A, 1, 2, st, {1, 1}}}, #{version => 3}, S1)).

%% The active answers an offer with a snapshot and a new claim, unless a
%% registration runs; another instance's offer is dismissed.
offer_test() ->
    {S, Es} = h({msg, {offer, ?B, 0}}, active()),
    ?assertEqual([{monitor, standby, ?B}, unsync, {snapshot, ?B, {1, 1}}, publish], Es),
    ?assertEqual(replicated, evatar_ha_instance:mode(S)),
    ?assertMatch({_, [{snapshot, ?B, {1, 2}}]}, h({msg, {resync, ?B, 0}}, S)),
    ?assertEqual({S, [{send, ?C, dismiss}]}, h({msg, {offer, ?C, 0}}, S)),
    {Lost, _} = h({cluster, {node_suspected, b}}, S),
    ?assertMatch({_, [{send, ?C, dismiss}]}, h({msg, {offer, ?C, 0}}, Lost)).

%% The standby's confirmation releases what was held for it.
confirm_test() ->
    S = active_with_standby(),
    ?assertEqual({S, [{release, 4}]}, h({msg, {confirm, ?B, 1, 4}}, S)),
    ?assertEqual({S, []}, h({msg, {confirm, ?C, 1, 4}}, S)).

%% The standby applies the active's events (watching it again if it was
%% lost); an active of a higher epoch elsewhere stops it.
standby_events_test() ->
    S = standby(),
    ?assertEqual([{apply, [ev]}], element(2, h({msg, {events, ?A, 1, [ev]}}, S))),
    {S1, _} = h({down, active, noconnection}, S),
    ?assertMatch([{monitor, active, ?A}, {apply, [ev]}], element(2, h({msg, {events, ?A, 1, [ev]}}, S1))),
    ?assertMatch({_, [{log, info, _}, {stop, {newer_instance, c, 2}}]},
                 h({msg, {events, ?C, 2, [ev]}}, S)).

%% Two actives: the lower epoch steps down (dismissing its standby and
%% closing its clients); the higher tells the lower it is stale.
meet_test() ->
    S = active_with_standby(),
    {_, Es} = h({msg, {peer_instance, ?C, active, 2}}, S),
    ?assertMatch([{send, ?B, dismiss}, {log, warning, #{what := stepping_down}},
                  {metric, evatar_step_downs_total}, {disconnect_all, stale_epoch, _},
                  {stop, {newer_instance, c, 2}}], Es),
    ?assertEqual({S, [{send, ?C, {stale, 3}}]},
                 h({msg, {peer_instance, ?C, fenced, 2}}, #{epoch => 3}, S)),
    ?assertEqual({S, []}, h({msg, {stale, ?A, 5}}, S)).

%% The standby's node lost: a configuration without it must be accepted
%% before anything goes out; then a new standby is placed.
standby_node_lost_test() ->
    {S, Es} = h({cluster, {node_suspected, b}}, active_with_standby()),
    ?assertMatch([{log, warning, #{what := standby_lost}}, {demonitor, standby},
                  {send, ?B, dismiss}, unsync | _], Es),
    ?assertEqual(held, evatar_ha_instance:mode(S)),
    ?assert(lists:member({timer, register, 50}, Es)),
    {S1, Es1} = h({timeout, register}, S),
    ?assert(lists:member({register, a, {1, 2}}, Es1)),
    {S2, Es2} = grant(Es1, S1),
    ?assertEqual(direct, evatar_ha_instance:mode(S2)),
    ?assertMatch([reconfirmed, release_all, {start_standby, b} | _], Es2).

%% The standby's process died (its node is up): go on without it at once.
standby_died_test() ->
    {S, Es} = h({down, standby, killed}, active_with_standby()),
    ?assertEqual(direct, evatar_ha_instance:mode(S)),
    ?assertMatch([{log, warning, _}, {demonitor, standby}, {send, ?B, dismiss}, unsync,
                  release_all, publish, {start_standby, b}, {timer, place, 1000}], Es).

%% A standby whose active's node went silent stands for election; won, it
%% takes over: held effects, logic timers re-armed, held resumes served.
takeover_test() ->
    {S, Es} = h({cluster, {node_suspected, a}}, standby()),
    ?assert(evatar_ha_instance:electing(S)),
    ?assert(lists:member({vote, a, 2, {1, 1}, ?A, false}, Es)),
    {S1, Es1} = grant(Es, S),
    ?assertEqual(active, evatar_ha_instance:role(S1)),
    ?assertEqual(held, evatar_ha_instance:mode(S1)),
    ?assert(lists:member({logic, {takeover, 2}, held}, Es1)),
    ?assert(lists:member(serve_held, Es1)),
    ?assert(lists:member(arm_logic_timers, Es1)),
    ?assert(has(fun(E) -> E =:= {register, b, {2, 1}} end, Es1)).

%% A standby that loses its election (a newer claim exists) stops and
%% answers its held resumes NotActive.
lost_test() ->
    {S, Es} = h({down, active, killed}, standby()),
    ?assert(lists:member({vote, b, 2, {1, 1}, ?A, true}, Es)),
    ?assertMatch({_, [reply_held, {log, info, _}, {stop, stale_claim}]},
                 h({msg, {vote_reply, p, 2, a, {refused, stale_claim}}}, S)).

%% A planned handover: the old active becomes the standby at once, in sync.
handover_test() ->
    St = standby(),
    ?assertEqual({St, []}, h({msg, {handover, ?A, 1, 2}}, #{version => 3}, St)),
    {S, Es} = h({msg, {handover, ?A, 1, 3}}, #{version => 3}, St),
    ?assert(lists:member({vote, c, 2, {1, 1}, ?A, true}, Es)),
    {S1, Es1} = grant(Es, S),
    ?assertEqual(?A, evatar_ha_instance:standby(S1)),
    ?assertEqual(replicated, evatar_ha_instance:mode(S1)),
    ?assertMatch([{monitor, standby, ?A}, {send, ?A, {handover_done, 2, {2, 1}}},
                  {synced_at, 0}, {flush, replicated}, publish],
                 lists:nthtail(length(Es1) - 5, Es1)).

%% A silent client link drops the entity and, with a synced standby, hands
%% the pairing over once the standby confirmed everything; the old active
%% becomes the standby on handover_done, or serves again if none comes.
silent_link_test() ->
    S = active_with_standby(),
    V = #{synced => true, version => 5, confirmed => 5},
    ?assertMatch({_, [{ensure_timer, silent, 2500}, {flush_maybe, replicated}]},
                 h({silent, [{<<"e">>, 9000}], 10000}, V, S)),
    {S1, Es} = h({silent, [{<<"e">>, 1000}], 10000}, V, S),
    ?assertEqual(handing_over, evatar_ha_instance:role(S1)),
    ?assertMatch([{log, warning, #{what := silent_link}}, {metric, _, silent_link},
                  {drop, <<"e">>, silent_link, _}, {ensure_timer, silent, 2500},
                  {timer, handover, 1000}, {flush, replicated}, {send, ?B, {handover, 5}}], Es),
    ?assertMatch({_, [{release, 6}, {send, ?B, {handover, 6}}]},
                 h({msg, {confirm, ?B, 1, 6}}, #{version => 6, confirmed => 5}, S1)),
    {S2, Es2} = h({msg, {handover_done, ?B, 2, {2, 1}}}, S1),
    ?assertEqual(standby, evatar_ha_instance:role(S2)),
    ?assertEqual(?B, evatar_ha_instance:active(S2)),
    ?assert(lists:member({monitor, active, ?B}, Es2)),
    ?assert(has(fun(E) -> element(1, E) =:= disconnect_all andalso element(2, E) =:= not_active end, Es2)),
    ?assertMatch({_, [{log, warning, #{what := handover_aborted}}]}, h({timeout, handover}, S1)),
    ?assertEqual(active, evatar_ha_instance:role(element(1, h({timeout, handover}, S1)))).

%% A handover under way does not keep an active from fencing: the
%% majority lost while handing over fences at once, and a handover that
%% times out without a majority and without word from the standby's node
%% fences instead of serving again (else a cut-off node would serve beside
%% the standby that took over: seen at slow HA timings in ha_SUITE).
handover_fences_without_majority_test() ->
    S = active_with_standby(),
    V = #{synced => true, version => 5, confirmed => 5},
    {S1, _} = h({silent, [{<<"e">>, 1000}], 10000}, V, S),
    ?assertEqual(handing_over, evatar_ha_instance:role(S1)),
    Cut = #{majority => false, heard => [a]},
    {S2, Es} = h({cluster, {quorum, false}}, Cut, S1),
    ?assertEqual(fenced, evatar_ha_instance:role(S2)),
    ?assert(lists:member({metric, evatar_fenced_total}, Es)),
    {S3, Es3} = h({timeout, handover}, Cut, S1),
    ?assertEqual(fenced, evatar_ha_instance:role(S3)),
    ?assertMatch([{log, warning, #{what := handover_aborted}}, {log, warning, #{what := fenced}} | _], Es3),
    %% The standby's node still heard: no fence, serving again.
    ?assertEqual(active, evatar_ha_instance:role(
                           element(1, h({timeout, handover}, #{majority => false}, S1)))).

%% Held deliveries were never sent: no silent link while holding.
silent_while_holding_test() ->
    {S, _} = h({cluster, {node_suspected, b}}, active_with_standby()),
    ?assertMatch({_, [{ensure_timer, silent, 2500}, {flush_maybe, held}]},
                 h({silent, [{<<"e">>, 0}], 10000}, S)).

%% Without a majority and without word from its standby's node, an active
%% fences; with a majority again it stands for election.
fence_test() ->
    S = active_with_standby(),
    ?assertEqual({S, []}, h({cluster, {quorum, false}}, #{majority => false}, S)),
    {S1, Es} = h({cluster, {quorum, false}}, #{majority => false, heard => [a]}, S),
    ?assertEqual(fenced, evatar_ha_instance:role(S1)),
    ?assertMatch([{log, warning, #{what := fenced}}, {metric, evatar_fenced_total},
                  {disconnect_all, fenced, _}, publish, reconfirmed], Es),
    {_, Es1} = h({cluster, {quorum, true}}, S1),
    ?assert(lists:member({vote, b, 2, {1, 1}, ?A, false}, Es1)).

%% A fenced active that wins again keeps its synced standby (it holds what
%% was released): the standby gets the claim {2, 1} with a snapshot taken
%% after the takeover, and the registration waits for its confirmation at
%% epoch 2 (an older confirmation does not let it go). Unsynced, or with
%% its node gone, the standby is dismissed as before.
fenced_rewin_keeps_standby_test() ->
    {S1, _} = h({cluster, {quorum, false}}, #{majority => false, heard => [a]},
                active_with_standby()),
    Synced = #{synced => true, version => 3, confirmed => 3},
    {S2, Es} = h({cluster, {quorum, true}}, Synced, S1),
    {S3, Es1} = grant_votes(Es, Synced, S2),
    ?assertEqual(active, evatar_ha_instance:role(S3)),
    ?assertEqual(?B, evatar_ha_instance:standby(S3)),
    ?assertEqual(replicated, evatar_ha_instance:mode(S3)),
    ?assertNot(has(fun(E) -> is_tuple(E) andalso element(1, E) =:= register end, Es1)),
    ?assertNot(lists:member({send, ?B, dismiss}, Es1)),
    [{logic, {takeover, 2}, replicated}, {snapshot, ?B, {2, 1}} | _] =
        lists:dropwhile(fun(E) -> E =/= {logic, {takeover, 2}, replicated} end, Es1),
    {S4, Es2} = h({msg, {confirm, ?B, 1, 3}}, #{epoch => 2}, S3),
    ?assertEqual([{release, 3}], Es2),
    {S5, Es3} = h({msg, {confirm, ?B, 2, 4}}, #{epoch => 2}, S4),
    ?assert(lists:member({register, b, {2, 1}}, Es3)),
    {S6, Es4} = grant(Es3, S5),
    ?assertEqual(?B, evatar_ha_instance:standby(S6)),
    ?assertEqual([reconfirmed], Es4),
    %% Not in sync: dismissed, the takeover registered at once.
    {S7, Es5} = h({cluster, {quorum, true}}, S1),
    {_, Es6} = grant_votes(Es5, #{}, S7),
    ?assert(lists:member({send, ?B, dismiss}, Es6)),
    ?assert(lists:member({register, b, {2, 1}}, Es6)).

grant_votes(Effects, V, S) ->
    lists:foldl(fun({vote, N, Ec, _, _, _}, {Acc, Es}) when N =/= c ->
                        {Acc1, Es1} = h({msg, {vote_reply, p, Ec, N, granted}}, V, Acc),
                        {Acc1, Es ++ Es1};
                   (_, Acc) -> Acc
                end, {S, []}, Effects).

%% A registration that settles neither way by its deadline fences.
deadline_test() ->
    {S, _} = h({cluster, {node_suspected, b}}, active_with_standby()),
    {S1, Es} = h({timeout, deadline}, S),
    ?assertEqual(fenced, evatar_ha_instance:role(S1)),
    ?assertMatch([{log, warning, #{what := registration_timeout}} | _], Es).

%% After a pause of its node an active asks the cluster again, keeping its
%% clients; inspections wait until the answer.
paused_test() ->
    {S, Es} = h(paused, active_with_standby()),
    ?assert(evatar_ha_instance:reconfirming(S)),
    ?assertMatch([pause_seen, {log, notice, #{what := reconfirming_after_pause}} | _], Es),
    {S1, Es1} = grant(Es, S),
    ?assertNot(evatar_ha_instance:reconfirming(S1)),
    ?assertEqual([reconfirmed], Es1).

%% The rebalancer's moves, made only with a synced standby.
rebalance_test() ->
    S = active_with_standby(),
    ?assertEqual({S, []}, h({msg, {rebalance, {handover, p}}}, S)),
    {S1, Es} = h({msg, {rebalance, {handover, p}}}, #{synced => true}, S),
    ?assertEqual(handing_over, evatar_ha_instance:role(S1)),
    ?assertMatch([{log, notice, #{what := rebalance_handover, to := b}} | _], Es),
    {S2, Es2} = h({msg, {rebalance, {standby, p, c}}}, #{synced => true}, S),
    ?assertEqual(held, evatar_ha_instance:mode(S2)),
    ?assertMatch([{log, notice, #{what := rebalance_standby}},
                  {demonitor, standby}, {send, ?B, dismiss}, unsync | _], Es2),
    ?assertEqual({S, []}, h({msg, {rebalance, {standby, p, b}}}, #{synced => true}, S)).

%% A standby whose active's node comes back asks for the events again.
active_back_test() ->
    {S, _} = h({cluster, {node_down, a}}, standby()),
    ?assertMatch({_, [{send, ?A, {resync, 3}}]}, h({cluster, {node_alive, a}}, #{version => 3}, S)).

%% ---------------------------------------------------------------------------
%% handle/3: the rules and the commit run inside, only I/O leaves
%% ---------------------------------------------------------------------------

config() ->
    {ok, C} = evatar_pairing_logic:config(#{agent_credential => <<"ca">>,
                                            avatar_credential => <<"cv">>}),
    C.

ctx() -> #{now => 1000, conns => #{<<"va1">> => va_conn}}.

io(Event, S) -> evatar_ha_instance:handle(Event, maps:merge(view(#{}), ctx()), S).

kind(E) when is_atom(E) -> E;
kind(E) -> element(1, E).

decision_only(E) ->
    lists:member(kind(E), [new_logic, install, apply, logic, arm_logic_timers, cancel_logic_timers,
                           release, release_all, flush, flush_maybe, unsync, synced_at,
                           reset_commit]).

%% The kinds of effect() the process carries out.
io_kind(E) ->
    lists:member(kind(E), [send, to_node, monitor, timer, ensure_timer, cancel_timer,
                           cancel_rule_timers, to_client, drop, reply_to, flush_later, stepped,
                           serving, pause_seen, publish, reconfirmed, reply_held,
                           serve_held, metric, log, postpone, stop]).

%% A new active makes its rules' state; what leaves is I/O, its timers are
%% the role machine's ({ha, Key}); a standby offering gets the rules' state.
only_io_test() ->
    {S, Es} = io({start, create, none}, evatar_ha_instance:new(p, ?A, config())),
    ?assertEqual(1, evatar_ha_instance:epoch(S)),
    ?assertEqual([], [E || E <- Es, decision_only(E)]),
    ?assertEqual([], [E || E <- Es, not io_kind(E)]),
    ?assertEqual([], [K || {T, K, _} <- Es, T =:= timer, element(1, K) =/= ha]),
    {S1, Es1} = io({msg, {offer, ?B, 0}}, S),
    Logic = evatar_ha_instance:logic(S1),
    ?assertEqual([{monitor, standby, ?B}, {send, ?B, {snapshot, 0, Logic, {1, 1}}}, publish],
                 Es1).

%% With a standby, an event is shipped in the batch and its reply waits for
%% the standby's confirmation; the standby applies the batch with the rules
%% and confirms it.
replicated_step_test() ->
    {SA0, _} = io({start, create, none}, evatar_ha_instance:new(p, ?A, config())),
    {SA1, [_, {send, ?B, {snapshot, 0, Logic, Claim}}, _]} = io({msg, {offer, ?B, 0}}, SA0),
    {SB0, _} = io({start, {standby_for, ?A}, none}, evatar_ha_instance:new(p, ?B, config())),
    {SB1, [{send, ?A, {confirm, 0}} | _]} = io({msg, {snapshot, ?A, 1, 0, Logic, Claim}}, SB0),
    Join = {join, agent, <<"va1">>, authenticated, <<"s">>},
    {ok, SA2, Es} = evatar_ha_instance:rules(Join, ctx(), SA1),
    ?assertMatch([{stepped, Join, _, 1000}, {timer, {join, <<"va1">>}, _}, {log, info, _}], Es),
    {SA3, []} = evatar_ha_instance:reply(from, ok, SA2),
    {SA4, [{send, ?B, {events, [{1, 1000, Join}] = Events}}]} = evatar_ha_instance:flush(SA3),
    {SB2, [{send, ?A, {confirm, 1}}]} = io({msg, {events, ?A, 1, Events}}, SB1),
    ?assertEqual([<<"va1">>], evatar_pairing_logic:entity_ids(evatar_ha_instance:logic(SB2))),
    ?assertMatch({_, [{reply_to, from, ok}]}, io({msg, {confirm, ?B, 1, 1}}, SA4)).
