%% @doc Unit tests of evatar_ha_role_machine: how an instance starts, how a
%% standby applies the active's events, when a held resume is answered.
-module(evatar_ha_role_machine_tests).

-include_lib("eunit/include/eunit.hrl").

-define(S, 250).

%% A new pairing is active at once; a standby started for an active
%% offers itself to it; a restart or a restore with no peer to ask stands
%% for election (a restore).
start_test() ->
    A = self(),
    ?assertMatch({_, [become_active]}, evatar_ha_role_machine:start(create, none, [b], ?S)),
    ?assertMatch({_, [{offer, A}]}, evatar_ha_role_machine:start({standby_for, A}, none, [b], ?S)),
    ?assertMatch({_, [{restore, []}]}, evatar_ha_role_machine:start(create, prev, [], ?S)),
    ?assertMatch({_, [{restore, []}]}, evatar_ha_role_machine:start(restore, none, [], ?S)),
    ?assertMatch({_, [{ask, [b]}, {timer, asked, 500}]}, evatar_ha_role_machine:start(restore, none, [b], ?S)),
    ?assertMatch({_, [{log, notice, #{what := pairing_restarted, previous := prev}},
                      {ask, [b, c]}, {timer, asked, 500}]},
                 evatar_ha_role_machine:start(create, prev, [b, c], ?S)).

%% A restart decides once every peer answered: an active (or fenced)
%% instance found takes it as its standby.
restart_finds_active_test() ->
    A = self(),
    {S0, _} = evatar_ha_role_machine:start(create, prev, [b, c], ?S),
    {S1, []} = evatar_ha_role_machine:starting({instance, b, none}, ?S, S0),
    ?assertMatch({_, [{offer, A}]},
                 evatar_ha_role_machine:starting({instance, c, info(fenced, A)}, ?S, S1)).

%% Only a standby answered (it is taking over), or a peer did not answer
%% (it may run anything): ask again later; every peer runs nothing (or
%% one still starting): a restore, naming them; nobody alive to ask: a
%% restore.
restart_finds_standby_test() ->
    {S0, _} = evatar_ha_role_machine:start(create, prev, [b, c], ?S),
    {S1, []} = evatar_ha_role_machine:starting({instance, b, info(standby, self())}, ?S, S0),
    {S2, [{timer, retry_ask, ?S}]} = evatar_ha_role_machine:starting({instance, c, none}, ?S, S1),
    {S3, [{ask, [b]}, {timer, asked, 500}]} =
        evatar_ha_role_machine:starting({timeout, retry_ask, [b]}, ?S, S2),
    {S4, [{timer, retry_ask, ?S}]} = evatar_ha_role_machine:starting({timeout, asked}, ?S, S3),
    {S5, [{ask, []}, {timer, asked, 500}]} =
        evatar_ha_role_machine:starting({timeout, retry_ask, []}, ?S, S4),
    ?assertMatch({_, [{restore, []}]}, evatar_ha_role_machine:starting({timeout, asked}, ?S, S5)),
    {S6, []} = evatar_ha_role_machine:starting({instance, b, none}, ?S,
                                        element(1, evatar_ha_role_machine:start(restore, none, [b, c], ?S))),
    ?assertMatch({_, [{restore, [b, c]}]},
                 evatar_ha_role_machine:starting({instance, c, info(starting, self())}, ?S, S6)).

%% Two actives: the lower epoch steps down, the higher tells it so; a
%% standby of another active stops for a higher epoch.
meet_test() ->
    Me = #{role => active, epoch => 3, node => a, pid => p1},
    ?assertEqual(tell_stale, evatar_ha_role_machine:meet(Me, #{role => fenced, epoch => 2, node => b, pid => p2})),
    ?assertEqual(keep, evatar_ha_role_machine:meet(Me, #{role => standby, epoch => 2, node => b, pid => p2})),
    ?assertEqual(step_down, evatar_ha_role_machine:meet(Me, #{role => active, epoch => 4, node => b, pid => p2})),
    ?assertEqual(stop, evatar_ha_role_machine:meet(#{role => standby, epoch => 3, node => a, pid => p1, peer => p3},
                                            #{role => active, epoch => 4, node => b, pid => p2})).

info(Role, Pid) -> #{pid => Pid, role => Role, epoch => 1, peer => undefined}.

%% Events apply in version order; one seen already is skipped; a gap
%% stops the batch and asks for a snapshot above what was applied.
apply_events_test() ->
    Apply = fun(E, _Now, L) -> L ++ [E] end,
    C0 = evatar_ha_commit:applied(2, evatar_ha_commit:new(0)),
    {L1, C1, {confirm, 4}} =
        evatar_ha_role_machine:apply_events([{2, 0, b}, {3, 0, c}, {4, 0, d}], Apply, [a], C0),
    ?assertEqual([a, c, d], L1),
    ?assertEqual(4, evatar_ha_commit:version(C1)),
    {L2, C2, {resync, 5}} =
        evatar_ha_role_machine:apply_events([{5, 0, e}, {7, 0, g}, {8, 0, h}], Apply, L1, C1),
    ?assertEqual([a, c, d, e], L2),
    ?assertEqual(5, evatar_ha_commit:version(C2)).

%% A held resume goes when the active was heard after it came (not while
%% an election runs), or when it waited suspect_ms + 2 heartbeats.
held_due_test() ->
    Held = [{f1, r, 100}, {f2, r, 300}, {f3, r, 500}],
    Ctx = #{suspect_ms => ?S, heartbeat_ms => 50, electing => false,
            heard_after => fun(Since) -> Since < 400 end},
    ?assertEqual({[{f1, r, 100}, {f2, r, 300}], [{f3, r, 500}]},
                 evatar_ha_role_machine:held_due(Held, 600, Ctx)),
    ?assertEqual({[{f1, r, 100}], [{f2, r, 300}, {f3, r, 500}]},
                 evatar_ha_role_machine:held_due(Held, 600, Ctx#{electing := true})),
    %% Never longer than 800 ms, whatever suspect_ms is.
    ?assertEqual({[{f1, r, 100}], [{f2, r, 300}, {f3, r, 500}]},
                 evatar_ha_role_machine:held_due(Held, 1000, Ctx#{suspect_ms := 5000, electing := true})),
    ?assertEqual(25, evatar_ha_role_machine:held_poll_ms(50)),
    ?assertEqual(5, evatar_ha_role_machine:held_poll_ms(4)).
