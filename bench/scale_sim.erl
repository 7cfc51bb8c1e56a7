%% @doc Benchmark: how far one cluster goes, in simulation (issue 30 item
%% 5; docs/scale.md). No nodes and no sockets: the pure HA core
%% (evatar_ha_core) and the pure placement planner (evatar_placement) run
%% in this one process for a cluster far larger than this machine holds, and
%% what they cost is measured as CPU here and as messages per node.
%%
%% 1. Takeover storm. N nodes, P pairings spread evenly; the node holding
%%    P/N actives dies. Each of those pairings' standbys (spread over the
%%    N-1 others) runs its election and its registration exactly as a node
%%    does: evatar_ha_core:handle/3 for the candidate, vote/5 and
%%    register/4 on every live voter's record (the ETS table
%%    evatar_cluster keeps, one record per pairing). Every request is
%%    answered at once and nothing is lost: the storm's floor, which the
%%    network, the schedulers and the sockets then add to. Printed: CPU of
%%    the candidates' and the voters' work, messages in all and per node,
%%    and the busiest node's share.
%% 2. Rebalance plan. After the dead node comes back empty, the coordinator
%%    plans the moves that spread the pairings again
%%    (evatar_placement:plan/2): its CPU and number of moves, at several N
%%    and P, and how long the rebalancer takes to carry them out at its
%%    rate (`rebalance_batch' pairings a second).
%% 3. Memory. The vote record each node keeps per pairing, measured in a
%%    real ETS table.
%%
%% `make bench-scale' runs it; BENCH_ARGS='[quick]' for a smoke run
%% (10 nodes, 100,000 pairings). Options: {nodes, N}, {pairings, P},
%% {plan_sizes, [{N, P}]}, {plan_limit_ms, Ms} (a plan not done by then is
%% reported as such).
-module(scale_sim).

-export([main/0, main/1]).

main() -> main([]).

-spec main([term()]) -> ok.
main(Opts) ->
    Quick = lists:member(quick, Opts),
    N = proplists:get_value(nodes, Opts, case Quick of true -> 10; false -> 50 end),
    P = proplists:get_value(pairings, Opts, case Quick of true -> 100000; false -> 1000000 end),
    PlanSizes = proplists:get_value(
                  plan_sizes, Opts,
                  case Quick of
                      true -> [{3, 1000}, {10, 1000}, {10, 10000}];
                      false -> [{3, 10000}, {5, 10000}, {10, 10000}, {20, 10000}, {50, 10000},
                                {5, 100000}, {5, 1000000}]
                  end),
    Limit = proplists:get_value(plan_limit_ms, Opts, 120000),
    io:format("EVATAR scale simulation (pure HA core and planner, one process, OTP ~s)~n~n",
              [erlang:system_info(otp_release)]),
    PerMsgUs = dist_cost(proplists:get_value(dist_messages, Opts, 100000)),
    storm(N, P, PerMsgUs),
    plan(PlanSizes, Limit),
    memory(N, P),
    catalogue(N, P, proplists:get_value(catalogue_sample, Opts, 100000)),
    ok.

%%% 1. The takeover storm

storm(N, P, PerMsgUs) ->
    Nodes = nodes_of(N),
    [Dead | Live] = Nodes,
    K = P div N,
    Ids = [integer_to_binary(I) || I <- lists:seq(1, K)],
    Standby = fun(I) -> lists:nth(1 + (I rem (N - 1)), Live) end,
    Cands = [{Id, Standby(I)} || {I, Id} <- lists:zip(lists:seq(1, K), Ids)],
    %% Before the kill: every live node holds each pairing's record as a
    %% registration of the active on Dead at {1, 1} left it.
    Rec0 = (evatar_ha_core:new_record())#{promised := 1, holder := {Dead, active},
                                          conf := {1, 1}, registered => true},
    Voters0 = maps:from_list([{V, maps:from_list([{Id, Rec0} || Id <- Ids])} || V <- Live]),
    Ctx = fun(Self) -> #{nodes => Nodes, heartbeat_ms => 50, epoch => 1, role => standby,
                         self => Self} end,
    Core0 = element(1, evatar_ha_core:handle({claim, {1, 1}}, Ctx(hd(Live)), evatar_ha_core:new())),
    garbage_collect(),
    %% Phase A: every standby stands for election (its votes to every node).
    {TA, Elect} = cpu(fun() ->
                              [begin
                                   {C, Effs} = evatar_ha_core:handle({elect, node_down, true},
                                                                     Ctx(S), Core0),
                                   {Id, S, C, [{V, Ec, Cl, D} || {vote, V, Ec, Cl, D} <- Effs]}
                               end || {Id, S} <- Cands]
                      end),
    %% Phase B: every live voter answers (the dead node does not).
    {TB, {Voters1, VoteReplies}} =
        cpu(fun() ->
                    lists:foldl(
                      fun({Id, S, _C, Votes}, {Vs, Acc}) ->
                              {Vs1, Rs} = lists:foldl(
                                            fun({V, _, _, _}, A) when V =:= Dead -> A;
                                               ({V, Ec, Cl, D}, {VsA, RA}) ->
                                                    Recs = maps:get(V, VsA),
                                                    case evatar_ha_core:vote(maps:get(Id, Recs), Ec,
                                                                             S, Cl, not D) of
                                                        {granted, R1} ->
                                                            {VsA#{V := Recs#{Id := R1}},
                                                             [{vote_reply, Ec, V, granted} | RA]};
                                                        {refused, Why} ->
                                                            {VsA, [{vote_reply, Ec, V, {refused, Why}} | RA]}
                                                    end
                                            end, {Vs, []}, Votes),
                              {Vs1, [lists:reverse(Rs) | Acc]}
                      end, {Voters0, []}, Elect)
            end),
    %% Phase C: the candidates count the grants; a majority wins and asks
    %% every node to register the new configuration.
    {TC, Won} = cpu(fun() ->
                            lists:zipwith(
                              fun({Id, S, C, _}, Replies) ->
                                      {C1, Effs} = feed(Replies, Ctx(S), C, []),
                                      {Id, S, C1, [{V, Cl} || {register, V, Cl} <- Effs],
                                       [W || {won, _, _} = W <- Effs]}
                              end, Elect, lists:reverse(VoteReplies))
                    end),
    Wins = length([1 || {_, _, _, _, [_]} <- Won]),
    %% Phase D: the voters record the registrations.
    {TD, RegReplies} =
        cpu(fun() ->
                    [[case evatar_ha_core:register(maps:get(Id, maps:get(V, Voters1)), E, Seq, S) of
                          {ok, _} -> {register_reply, Cl, V, ok};
                          {refused, Why} -> {register_reply, Cl, V, {refused, Why}}
                      end || {V, {E, Seq} = Cl} <- Regs, V =/= Dead]
                     || {Id, S, _, Regs, _} <- Won]
            end),
    %% Phase E: the candidates count the registrations: registered, serving.
    {TE, Registered} =
        cpu(fun() ->
                    lists:zipwith(fun({_, S, C, _, _}, Replies) ->
                                          {_, Effs} = feed(Replies, Ctx(S), C, []),
                                          lists:member(registered, Effs)
                                  end, Won, RegReplies)
            end),
    Served = length([1 || true <- Registered]),
    Votes = lists:sum([length(V) || {_, _, _, V} <- Elect]),
    Regs = lists:sum([length(R) || {_, _, _, R, _} <- Won]),
    %% Requests to the dead node are sent and never answered.
    Replies = lists:sum([length(R) || R <- VoteReplies]) + lists:sum([length(R) || R <- RegReplies]),
    Msgs = Votes + Regs + Replies,
    CandUs = TA + TC + TE,
    VoterUs = TB + TD,
    %% The busiest node: a voter for every pairing, and candidate for its
    %% share (K / (N - 1), rounded up).
    Share = (K + N - 2) div (N - 1),
    NodeUs = VoterUs / (N - 1) + CandUs / K * Share,
    NodeMsgs = 4 * K + Share * 4 * N,
    io:format("1. Takeover storm: ~b nodes, ~b pairings, the node holding ~b actives dies~n",
              [N, P, K]),
    io:format("   elections won ~b of ~b, registered and serving ~b~n", [Wins, K, Served]),
    io:format("   quorum ~b of ~b nodes: ~b messages a takeover (votes, registrations and their "
              "answers), ~b in all~n",
              [evatar_ha_core:quorum_size(N), N, round(Msgs / max(1, K)), Msgs]),
    io:format("   CPU, pure logic: candidates ~.1f ms, voters ~.1f ms, ~.2f us a takeover~n",
              [CandUs / 1000, VoterUs / 1000, (CandUs + VoterUs) / max(1, K)]),
    io:format("   the busiest node: ~b messages to handle (in and out), ~.1f ms of HA logic~n",
              [NodeMsgs, NodeUs / 1000]),
    io:format("   with this machine's distribution cost (~.1f us of CPU a message, sent and "
              "received, both VMs):~n   ~b ms of CPU on the busiest node, ~.1f s on one core~n~n",
              [PerMsgUs, round(NodeUs / 1000 + NodeMsgs * PerMsgUs / 1000),
               (NodeUs + NodeMsgs * PerMsgUs) / 1.0e6]),
    ok.

feed([], _Ctx, C, Acc) -> {C, lists:append(lists:reverse(Acc))};
feed([Event | Rest], Ctx, C, Acc) ->
    {C1, Effs} = evatar_ha_core:handle(Event, Ctx, C),
    feed(Rest, Ctx, C1, [Effs | Acc]).

%%% 2. The rebalance plan

plan(Sizes, Limit) ->
    io:format("2. Rebalance plan after a node comes back empty (evatar_placement:plan/2; "
              "at most ~b s each)~n", [Limit div 1000]),
    io:format("   ~6s ~9s ~8s ~12s ~12s ~16s~n",
              ["nodes", "pairings", "moves", "plan CPU ms", "us a move", "carried out in"]),
    Batch = 2,
    _ = [begin
             Placement = after_rejoin(N, P),
             Nodes = nodes_of(N),
             Parent = self(),
             Pid = spawn(fun() -> Parent ! {self(), cpu(fun() -> evatar_placement:plan(Nodes, Placement) end)} end),
             receive
                 {Pid, {Us, Moves}} ->
                     M = length(Moves),
                     io:format("   ~6b ~9b ~8b ~12.1f ~12.1f ~16s~n",
                               [N, P, M, Us / 1000, Us / max(1, M), duration(M / Batch)])
             after Limit ->
                     exit(Pid, kill),
                     io:format("   ~6b ~9b ~8s ~12s ~12s ~16s~n",
                               [N, P, "-", "> limit", "-", "-"])
             end
         end || {N, P} <- Sizes],
    io:format("   (carried out at the rebalancer's default rate: rebalance_batch ~b pairings "
              "a round, a round a second)~n~n", [Batch]),
    ok.

%% P pairings balanced over the N-1 nodes that stayed (each active's
%% standby on the next of them), the first node back and empty.
after_rejoin(N, P) ->
    [_Back | Stayed] = nodes_of(N),
    T = list_to_tuple(Stayed),
    M = N - 1,
    maps:from_list([{integer_to_binary(I),
                     {element(1 + I rem M, T), element(1 + (I + 1 + I div M) rem M, T)}}
                    || I <- lists:seq(1, P)]).

duration(S) when S < 120 -> io_lib:format("~.1f s", [S]);
duration(S) when S < 7200 -> io_lib:format("~.1f min", [S / 60]);
duration(S) -> io_lib:format("~.1f h", [S / 3600]).

%%% 3. Memory

memory(N, P) ->
    T = ets:new(votes, [set]),
    Rec = (evatar_ha_core:new_record())#{promised := 3, holder := self(), conf := {3, 7},
                                         registered => true},
    Count = 100000,
    Before = ets:info(T, memory),
    _ = [ets:insert(T, {integer_to_binary(I + 1000000000), Rec}) || I <- lists:seq(1, Count)],
    Words = (ets:info(T, memory) - Before) / Count,
    Bytes = Words * erlang:system_info(wordsize),
    ets:delete(T),
    io:format("3. Memory: a vote record costs ~b bytes a pairing on every node "
              "(~b pairings: ~.1f MiB a node, for the votes alone)~n",
              [round(Bytes), P, Bytes * P / 1048576]),
    io:format("   full-mesh distribution: ~b connections for ~b nodes; heartbeats every 50 ms: "
              "~b messages a second in the cluster, ~b a node~n",
              [N * (N - 1) div 2, N, N * (N - 1) * 20, 2 * (N - 1) * 20]),
    ok.

%%% 4. The catalogue's anti-entropy

%% Every node sends its whole catalogue to every alive peer each
%% `catalogue_sync_ms' (10 s) and merges what it receives
%% (evatar_catalogue_rules:changed/2): the size of an entry as it travels
%% (term_to_binary of an entry with the configuration a pairing stores,
%% credentials hashed), and the merge's CPU for Sample entries, scaled to P.
catalogue(N, P, Sample) ->
    {ok, Config} = evatar_pairing_logic:config(
                     #{agent_credential => <<"a-credential-of-32-bytes-or-so-00">>,
                       avatar_credential => <<"another-credential-of-32-bytes-0">>,
                       join_timeout => 30000, feedback_timeout => 120000}),
    [Home | _] = nodes_of(N),
    Entry = fun(I) -> {iolist_to_binary(["pairing-", integer_to_list(I)]),
                       {1, 1764633600000 + I, Home}, {live, Config, Home}} end,
    Ours = [Entry(I) || I <- lists:seq(1, Sample)],
    Theirs = [Entry(I) || I <- lists:seq(1, Sample)],
    Bytes = byte_size(term_to_binary(Entry(123456))),
    {Us, []} = cpu(fun() -> evatar_catalogue_rules:changed(Ours, Theirs) end),
    PerEntryUs = Us / Sample,
    Period = 10,
    io:format("4. Catalogue anti-entropy (the whole catalogue to every alive peer every ~b s):~n"
              "   an entry is ~b bytes on the wire; merging ~b received entries costs ~.2f us each~n"
              "   at ~b pairings and ~b nodes a node sends and receives ~.1f MiB a second each way "
              "and spends ~.1f s of CPU a second merging~n",
              [Period, Bytes, Sample, PerEntryUs, P, N,
               P * Bytes * (N - 1) / Period / 1048576, P * (N - 1) * PerEntryUs / Period / 1.0e6]),
    ok.

%%% The cost of one distribution message

%% CPU microseconds a vote-sized message costs, sent by one VM and received
%% by another (both VMs' CPU, the request and its answer counted as two
%% messages): one peer node on loopback, Count requests 64 in flight.
dist_cost(Count) ->
    _ = os:cmd("epmd -daemon"),
    {ok, _} = net_kernel:start(['scale_sim@127.0.0.1', longnames]),
    {ok, Peer, Node} = peer:start_link(#{name => 'scale_sim_peer', host => "127.0.0.1",
                                         longnames => true,
                                         args => ["-pa", filename:dirname(code:which(?MODULE))]}),
    Echo = erpc:call(Node, erlang, spawn,
                     [fun Loop() -> receive {From, M} -> From ! {self(), M}, Loop() end end]),
    Msg = {vote, <<"pairing-000042">>, 7, {6, 3}, false},
    {R0, _} = erlang:statistics(runtime),
    {P0, _} = erpc:call(Node, erlang, statistics, [runtime]),
    ok = pump(Echo, Msg, Count, 64),
    {R1, _} = erlang:statistics(runtime),
    {P1, _} = erpc:call(Node, erlang, statistics, [runtime]),
    peer:stop(Peer),
    PerMsg = ((R1 - R0) + (P1 - P0)) * 1000 / (2 * Count),
    io:format("Distribution on this machine: ~b requests and answers between two nodes on "
              "loopback, ~.1f us of CPU a message (both VMs)~n~n", [Count, PerMsg]),
    PerMsg.

pump(Echo, Msg, Count, Window) ->
    Start = min(Window, Count),
    _ = [Echo ! {self(), Msg} || _ <- lists:seq(1, Start)],
    pump_loop(Echo, Msg, Count - Start, Count).

pump_loop(_Echo, _Msg, _ToSend, 0) -> ok;
pump_loop(Echo, Msg, ToSend, Outstanding) ->
    receive
        {Echo, _} when ToSend > 0 ->
            Echo ! {self(), Msg},
            pump_loop(Echo, Msg, ToSend - 1, Outstanding - 1);
        {Echo, _} ->
            pump_loop(Echo, Msg, 0, Outstanding - 1)
    end.

%%% Helpers

nodes_of(N) ->
    %% A fixed, small set of names this benchmark makes itself.
    [list_to_atom(lists:flatten(io_lib:format("sim~3..0b@scale", [I]))) || I <- lists:seq(1, N)].

%% {Microseconds of CPU, Result}: the VM's CPU time (statistics(runtime),
%% millisecond resolution) over F, which runs in this one process.
cpu(F) ->
    {T0, _} = erlang:statistics(runtime),
    R = F(),
    {T1, _} = erlang:statistics(runtime),
    {(T1 - T0) * 1000, R}.
