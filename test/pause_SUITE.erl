%% Common Test suite of pauses of a node's own schedulers (issue 16): a
%% real OS-process node stopped with SIGSTOP and woken with SIGCONT, as a
%% laptop lid, a long garbage collection or a load spike does to it, while
%% a VA and an Avatar (HA clients of the bridge, evatar_test_traffic) drive
%% requests, feedback and sensor streams through it.
%%
%% - lone: a single node with no peers, EVATAR's default timings and
%%   bridge heartbeat. Whatever the pause, nobody else can hold its
%%   pairings: it never fences, the pairing keeps its epoch (a fence would
%%   end in a new election and a new epoch), no client is ever told
%%   `Fenced', traffic resumes, and nothing accepted is lost or duplicated.
%% - cluster: three nodes (slower timings than the defaults, so the load of
%%   a shared machine alone does not look like a pause). A pause longer
%%   than the lease but shorter than suspect_ms changes nothing: the same
%%   active, the same epoch, the same standby, no client told `Fenced'. A pause long enough for the others to suspect the node
%%   is a failover: the standby takes over, the woken node never reports a
%%   second active (it asks the cluster before it answers, and learns it
%%   lost), it rejoins and takes a standby again, and nothing accepted is
%%   lost or duplicated (evatar_test_checker).
%%
%% Behaviour only: no case asserts how long anything took.
-module(pause_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-compile([export_all, nowarn_export_all]).

-define(TIMEOUT, evatar_test_time:guard()).
%% Slower than the defaults, so the load of a shared two-core machine does
%% not look like a pause, and with room between the lease and suspect_ms
%% for a pause that outlasts the one but not the other.
-define(CLUSTER_TIMING, evatar_test_time:ha_timing(#{suspect_ms => 2000})).
%% Pauses of the lone node, ms: under, around and well over suspect_ms
%% (250 by default), the clients' 3 heartbeats and the ack timeout.
-define(LONE_PAUSES, [100, 250, 400, 1000, 2000, 5500]).
%% Longer than the cluster's lease, well under its suspect_ms: the node's
%% own pause must not cost it its majority.
-define(SHORT_PAUSE, evatar_test_time:cluster_ms(1000)).

suite() -> [{timetrap, evatar_test_time:ms(300000)}].

all() ->
    [{group, lone}, {group, cluster}].

groups() ->
    [{lone, [], [lone_pauses_never_fence]},
     {cluster, [], [short_pause_changes_nothing, long_pause_fails_over]}].

%% As ha_SUITE: this node becomes distributed (hidden) to drive the nodes.
init_per_suite(Config) ->
    ha_SUITE:init_per_suite(Config).

end_per_suite(Config) ->
    ha_SUITE:end_per_suite(Config).

init_per_group(Group, Config) ->
    Dir = filename:join(?config(priv_dir, Config), atom_to_list(Group)),
    ok = filelib:ensure_path(Dir),
    Opts = case Group of
               %% The defaults of the release: evatar's timings and the
               %% bridge's heartbeat (conn options left to the listener).
               lone -> #{n => 1, net => none, evatar => [], conn => #{}};
               cluster -> #{evatar => ?CLUSTER_TIMING}
           end,
    {ok, C} = evatar_test_cluster:start(Opts#{dir => Dir, prefix => "pz" ++ atom_to_list(Group)}),
    ct:pal("~p: ~p", [Group, evatar_test_cluster:info(C)]),
    [{cluster, C}, {group, Group} | Config].

end_per_group(_Group, Config) ->
    ok = evatar_test_cluster:stop(?config(cluster, Config)).

init_per_testcase(Case, Config) ->
    [{pairing, iolist_to_binary(["pz-", atom_to_list(Case)])} | Config].

%% As ha_SUITE: every node up and formed again, the case's pairing deleted.
end_per_testcase(Case, Config) ->
    ha_SUITE:end_per_testcase(Case, Config).

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% A lone node paused for 100 ms to 5.5 s, one pause after the other under
%% traffic: after each, the same instance is active with the same epoch,
%% a request gets its feedback, and no client was ever told Fenced; at the
%% end every accepted signal arrived exactly once.
lone_pauses_never_fence(Config) ->
    {C, Id, Pair} = start(Config),
    {ok, 1, #{epoch := E0, active := Pid}} = evatar_test_pairing:active(C, Id),
    _ = [begin
             ok = pause(C, 1, Ms),
             {ok, Epoch} = evatar_test_traffic:round_trip(Pair, ?TIMEOUT),
             ?assertEqual(E0, Epoch),
             ?assertMatch({ok, 1, #{epoch := E0, active := Pid}}, evatar_test_pairing:active(C, Id)),
             ok = never_fenced(Pair, {pause, Ms})
         end || Ms <- ?LONE_PAUSES],
    finish(Pair).

%% A pause of the active's node longer than the lease, well under
%% suspect_ms: no fencing and no failover (the same active, the same
%% epoch, the same standby), no client told Fenced.
short_pause_changes_nothing(Config) ->
    {C, Id, Pair} = start(Config),
    ok = evatar_test_pairing:await_healthy(C, Id, ?TIMEOUT),
    {ok, 1, #{epoch := E0, active := Pid, standby_node := SN}} = evatar_test_pairing:active(C, Id),
    ok = pause(C, 1, ?SHORT_PAUSE),
    {ok, Epoch} = evatar_test_traffic:round_trip(Pair, ?TIMEOUT),
    ?assertEqual(E0, Epoch),
    ?assertMatch({ok, 1, #{epoch := E0, active := Pid, standby_node := SN}},
                 evatar_test_pairing:active(C, Id)),
    ok = never_fenced(Pair, short_pause),
    finish(Pair).

%% The active's node paused until its standby took over: the woken node
%% never reports a second active, rejoins the cluster, and takes standbys
%% again (shown by losing the third node: the pairing's new standby goes
%% to the once paused node); nothing accepted is lost or duplicated.
long_pause_fails_over(Config) ->
    {C, Id, Pair} = start(Config),
    T = ha_SUITE:trace(C),
    ok = evatar_test_pairing:await_healthy(C, Id, ?TIMEOUT),
    {ok, 1, #{epoch := E0, standby_node := SN}} = evatar_test_pairing:active(C, Id),
    S = evatar_test_cluster:index(C, SN),
    ok = evatar_test_cluster:stall(C, 1),
    {ok, S, #{epoch := E1}} = evatar_test_pairing:await_active(
                                 C, Id, fun(_I, #{epoch := E}) -> E > E0 end, ?TIMEOUT),
    Mark = evatar_test_trace:mark(T),
    ok = evatar_test_cluster:resume(C, 1),
    ok = ha_SUITE:woken_active_gives_up(T, C, 1, Id, Mark),
    {ok, Epoch} = evatar_test_traffic:round_trip(Pair, ?TIMEOUT),
    ?assert(Epoch >= E1),
    ok = evatar_test_cluster:await_formed(C, ?TIMEOUT),
    ok = evatar_test_pairing:await_healthy(C, Id, ?TIMEOUT),
    {ok, S, _} = evatar_test_pairing:active(C, Id),
    ok = ha_SUITE:never_took_over(T, C, 1, Id, Mark),
    ok = evatar_test_trace:stop(T),
    %% Node 1 is a full member again: with the third node gone, the
    %% pairing's standby goes there.
    [Third] = [I || I <- [1, 2, 3], I =/= 1, I =/= S],
    ok = evatar_test_cluster:kill(C, Third),
    ok = evatar_test_cluster:await(fun() ->
                                  case evatar_test_pairing:active(C, Id) of
                                      {ok, S, #{synced := true, standby_node := N}} ->
                                          N =:= evatar_test_cluster:node(C, 1);
                                      _ ->
                                          false
                                  end
                          end, ?TIMEOUT, {standby_on, 1}),
    ok = evatar_test_pairing:await_healthy(C, Id, ?TIMEOUT),
    finish(Pair).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

%% A pairing active on node 1 with a VA and an Avatar bound and traffic
%% flowing (in a cluster, with its standby in sync), as in ha_SUITE.
start(Config) ->
    ha_SUITE:start(Config).

%% SIGSTOP of node I's OS process, SIGCONT Ms later. The pause's length is
%% what the cases are about (under or over the lease, suspect_ms, the
%% clients' heartbeats), so this sleep stays: no event marks its end.
pause(C, I, Ms) ->
    ok = evatar_test_cluster:stall(C, I),
    timer:sleep(Ms),
    ok = evatar_test_cluster:resume(C, I).

%% No client was told Fenced: none reconnected for that reason.
never_fenced(Pair, When) ->
    #{va := #{reconnects := RVa}, av := #{reconnects := RAv}} = evatar_test_traffic:history(Pair),
    case [R || #{reason := {refused, <<"Fenced">>, _} = R} <- RVa ++ RAv] of
        [] -> ok;
        Fenced -> ct:fail({fenced, When, Fenced})
    end.

%% The checks every HA case ends with (ha_SUITE): nothing accepted lost or
%% duplicated, epochs never going back at a receiver, no client given up.
finish(Pair) ->
    ha_SUITE:finish(Pair).
