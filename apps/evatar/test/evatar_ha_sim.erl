%% @doc A deterministic simulation of one pairing's instances on two or
%% three nodes, in one process, running the code the node runs for each
%% instance: the pure `evatar_ha_instance' (the role machine with
%% `evatar_ha_core' and `evatar_ha_role_machine', the
%% pairing's rules `evatar_pairing_logic' and the output commit
%% `evatar_ha_commit'). This module executes its I/O effects on a simulated
%% world instead of processes, as `evatar_pairing' does in the node. The
%% pairing is an agent (the sender, whose component asks the Avatar's) and
%% an Avatar (the receiver), both joined with a session and described; a
%% signal is a light request, routed by the rules to the receiver and
%% acknowledged to the sender; a routing is the signal's epoch and
%% Sequence as the rules stamped it.
%%
%% The world: nodes with a voter record each (what `evatar_cluster' keeps:
%% in memory, and on disc by `evatar_ha_promises', written before the
%% answer goes out),
%% heartbeats every 50 ms, suspicion after 250 ms, a lease of 150 ms;
%% messages between nodes with a latency, over links that can be cut; a
%% node can be paused (its clock stops, messages to it queue) or crashed
%% (its instance and its memory go, messages to it are lost; its disc
%% stays) and restarted (its voter reads its promises back); a node may
%% restore the pairing (`{restore, N}': the catalogue found nobody running
%% it, from a view that may be wrong). Peers answer a starting instance's
%% `ask' as evatar_cluster does. One sender
%% client and one receiver client reach every running node.
%%
%% Clocks: everything the HA code times (heartbeats, suspicion, the lease,
%% the pause a node finds it had, every timer an instance arms) is read on
%% its own node's monotonic clock, as evatar_cluster and evatar_pairing
%% read erlang:monotonic_time/1. Each node's clock starts at an offset of
%% its own (from the `seed' of {@link new/2}; again at each boot), so a
%% decision that compared readings of two nodes, or a reading with a
%% constant, would show; and runs at its own rate (`rates', in thousandths
%% of real time, or the command `{skew, N, Rate}' from then on): node N's
%% timers fire after Ms x 1000 / Rate of simulated real time, and its
%% suspicion and lease take as long. Heartbeats are taken as continuous
%% (every node hears every running, connected node at every step of at
%% most a heartbeat), whatever the sender's rate.
%%
%% The drift the design tolerates: an active cut off stops serving when
%% lease_ms (150) has passed on its clock without a majority, checked every
%% heartbeat (50); a voter grants the pairing to another once suspect_ms
%% (250) passed on its clock without hearing it. So the active's clock may
%% run no slower than (lease_ms + heartbeat_ms) / suspect_ms = 0.8 of any
%% voter's. The schedules' rates are within 10 % of real time (900 to
%% 1100: two clocks within 0.82 of each other), a hundred times the drift
%% of a quartz clock (about 100 ppm) and ten times the 1 % by which
%% Erlang's time correction may change the rate of the monotonic clock.
%%
%% Checked after every command ({@link check/1}):
%% <ul>
%% <li>at most one instance serves at the highest epoch (role active, not
%% holding its effects);</li>
%% <li>no accepted signal is lost: one the sender was told was accepted
%% (docs/ha-design.md section 9: applied and in the standby's history, then
%% acknowledged) is held by a live instance, and by the serving instance
%% of the highest epoch;</li>
%% <li>no accepted signal is delivered twice: the receiver never gets one
%% SignalID routed twice (two different routings, which its library could
%% not tell apart); a signal acknowledged while degraded and covered again
%% later gets no routing but those it had when it was covered again;</li>
%% <li>with three nodes, no epoch is won by two instances (a promise
%% outlives a crash of its node; a cluster of two decides alone, and its
%% epochs are checked by what its clients see);</li>
%% <li>with three nodes, the lease: no two instances serve at once, at any
%% epochs, while no more than one failure happened and the pairing was not
%% restored from a view that missed an instance (a woken node counts its
%% pause as a stall past lease + heartbeat on its own clock,
%% evatar_ha_membership:stall_ms/2, so every pause a peer within the drift
%% bound could have suspected is noticed).</li>
%% </ul>
%% and, by {@link live/3}, liveness once the faults stop (docs/ha.md section
%% 6), or by {@link settle/1}, a looser form: once every node runs and hears
%% the others for long enough, some instance serves.
-module(evatar_ha_sim).

-export([new/1, new/2, run/2, step/2, check/1, settle/1, serving/1, live/3, applied/1]).
-export_type([clocks/0]).

-define(HB, 50).
-define(SUSPECT, 250).
-define(LEASE, 150).
%% No silent links: the receiver never acknowledges, and its link is never
%% found silent within a run.
-define(CLIENT_ACK_TIMEOUT, 3600000).
-define(LATENCY, 3).
%% The pairing's clients (evatar_ha_logic_tests' fixtures).
-define(VA, <<"va1">>).
-define(AV, <<"av1">>).

%% ---------------------------------------------------------------------------
%% The world
%% ---------------------------------------------------------------------------

%% How each node's monotonic clock runs: `seed' picks the offset every
%% node's clock starts at (again at each boot), `rates' how fast it runs, in
%% thousandths of real time (1000 by default; 900 is 10 % slow).
-type clocks() :: #{seed => integer(), rates => #{atom() => pos_integer()}}.

%% @doc A cluster of `N' nodes (2 or 3) with the pairing active on the
%% first, every clock at the true rate from an offset of its own.
-spec new(2 | 3) -> map().
new(N) ->
    new(N, #{}).

%% @doc {@link new/1} with the clocks `Clocks' gives.
-spec new(2 | 3, clocks()) -> map().
new(N, Clocks) ->
    Nodes = lists:sublist([n1, n2, n3], N),
    Seed = maps:get(seed, Clocks, 0),
    Rates = maps:merge(maps:from_list([{Nd, 1000} || Nd <- Nodes]), maps:get(rates, Clocks, #{})),
    W0 = #{now => 0, names => Nodes, insts => #{}, next_ref => 1, msgs => [], seq => 0, cut => [],
           sender => #{next => 1, sent => [], acked => [], degraded => [], epoch => 0},
           receiver => #{got => #{}, epoch => 0, excused => #{}}, violations => [],
           last_change => 0, seed => Seed, rates => Rates, boots => 0, config => config()},
    W1 = W0#{nodes => maps:from_list([{Nd, node0(Nodes, clock0(Nd, W0))} || Nd <- Nodes])},
    start_active(n1, W1).

node0(Nodes, {_, L, _} = Clock) ->
    #{status => up, voter => evatar_ha_core:new_record(), disk => evatar_ha_core:new_record(),
      heard => maps:from_list([{N, L} || N <- Nodes]), alive => maps:from_list([{N, true} || N <- Nodes]),
      quorum => true, inst => undefined, paused_at => undefined, down_at => undefined,
      clock => Clock}.

%% A node's monotonic clock, as erlang:monotonic_time/1 gives it: it starts
%% anywhere (each boot of the VM at an offset of its own, which nothing may
%% depend on: only differences of one node's readings are used) and runs at
%% its node's rate. `{RealMs, LocalMs, Rate}': it read LocalMs at RealMs.
clock0(N, #{now := Now, seed := Seed, boots := Boots, rates := Rates}) ->
    Offset = erlang:phash2({Seed, N, Boots}, 1 bsl 32) * 1000 - (1 bsl 41),
    {Now, Offset, maps:get(N, Rates)}.

%% What node N's clock reads now (milliseconds).
local(N, #{nodes := Nodes, now := Now}) ->
    {R0, L0, Rate} = maps:get(clock, maps:get(N, Nodes)),
    L0 + (Now - R0) * Rate div 1000.

%% @doc Runs a list of commands, checking after each; returns the world.
-spec run([term()], map()) -> map().
run(Cmds, W) ->
    lists:foldl(fun(C, Acc) -> check(step(C, Acc)) end, W, Cmds).

%% @doc One command.
-spec step(term(), map()) -> map().
step({tick, Ms}, W) -> advance(Ms, W);
step({signal, N}, W) -> client_send(N, W);
step({drop, _} = C, W) -> fault(C, W);
step({dup, _} = C, W) -> fault(C, W);
step({delay, _, _} = C, W) -> fault(C, W);
step({skew, _, _} = C, W) -> fault(C, W);
step(C, #{now := Now} = W) -> count_fault(C, W, fault(C, W#{last_change := Now})).

%% The guarantee holds while no more than one of the two instances fails
%% before a new standby is synced (docs/ha-design.md section 9): a second
%% failure (a crash, a pause, a cut between the instances' nodes) leaves
%% what was accepted until then outside it. The crash of a node without an
%% instance is not one: its voter's promises are on its disc (the liveness
%% schedules, docs/ha.md section 6, count every crash).
count_fault(C, #{insts := Insts}, W) ->
    Homes = [N || #{node := N} <- maps:values(Insts)],
    Hit = case C of
              {crash, N} -> lists:member(N, Homes);
              {pause, N} -> lists:member(N, Homes);
              {isolate, N} -> lists:member(N, Homes);
              {cut, A, B} -> lists:member(A, Homes) andalso lists:member(B, Homes);
              {restore, N} ->
                  %% A restore from a view that misses an instance holding
                  %% the pairing's state (its node not heard by the
                  %% restorer): outside the guarantee, like a second
                  %% failure (docs/ha.md section 6, "Two restorers").
                  running(N, W) andalso inst_on(N, W) =/= undefined
                      andalso [I || #{node := M} = I <- maps:values(Insts), M =/= N,
                                    holds_state(I)] =/= [];
              _ -> false
          end,
    W1 = case {Hit, C} of
             {true, {restore, R}} ->
                 %% Only a restore that started an instance.
                 case inst_on(R, W) of
                     #{ref := Ref} when not is_map_key(Ref, Insts) -> W#{restored_wrong => true};
                     _ -> W
                 end;
             _ ->
                 W
         end,
    count_hit(Hit, W1).

count_hit(Hit, #{sender := #{acked := Acked} = Snd} = W) ->
    case {Hit, maps:get(faults, W, 0)} of
        {false, _} -> W;
        {true, 0} -> W#{faults => 1};
        {true, F} -> W#{faults => F + 1,
                        sender := Snd#{degraded := lists:usort(Acked ++ maps:get(degraded, Snd))}}
    end.

fault({cut, A, B}, #{cut := Cut} = W) when A =/= B -> W#{cut := lists:usort([link(A, B) | Cut])};
fault({cut, _, _}, W) -> W;
fault({isolate, A}, #{names := Ns, cut := Cut} = W) ->
    W#{cut := lists:usort([link(A, B) || B <- Ns, B =/= A] ++ Cut)};
fault(heal, W) -> unpend_running(W#{cut := []});
fault({pause, N}, W) -> pause(N, W);
fault({resume, N}, W) -> resume(N, W);
fault({crash, N}, W) -> crash(N, W);
fault({restart, N}, W) -> restart(N, W);
fault({restore, N}, W) -> restore(N, W);
fault({drop, I}, #{msgs := Ms0} = W) ->
    %% A message lost on its way; never a node's own view of its
    %% connections (nodedown) nor a monitor's DOWN.
    case [M || {_, _, _, Msg} = M <- Ms0, element(1, Msg) =/= nodedown,
               element(1, Msg) =/= event] of
        [] -> W;
        Ms -> W#{msgs := Ms0 -- [lists:nth(1 + I rem length(Ms), Ms)]}
    end;
fault({dup, I}, #{msgs := Ms0} = W) ->
    %% Erlang delivers a message once; what comes twice is what is sent
    %% again: votes and registrations (retried) and their answers, and
    %% event batches and confirmations (which a gap or a resync repeats).
    case [M || {_, _, _, Msg} = M <- Ms0, element(1, Msg) =:= vote orelse
                                           element(1, Msg) =:= register orelse
                                           element(1, Msg) =:= vote_reply orelse
                                           element(1, Msg) =:= register_reply orelse
                                           element(1, Msg) =:= events orelse
                                           element(1, Msg) =:= confirm] of
        [] -> W;
        Ms -> M = lists:nth(1 + I rem length(Ms), Ms),
              W#{msgs := lists:sort([M | Ms0])}  % twice in a row
    end;
fault({delay, N, D}, #{msgs := Ms} = W) ->
    %% A slow link into N: everything on its way there comes D ms later.
    Floor = maps:get(floor, W, #{}),
    Ms1 = [case to_node(To, W) of
               N -> {At + D, S, To, Msg};
               _ -> {At, S, To, Msg}
           end || {At, S, To, Msg} <- Ms],
    W#{msgs := lists:sort(Ms1), floor => Floor#{N => maps:get(N, Floor, 0) + D}};
fault({skew, N, Rate}, #{nodes := Nodes, rates := Rates} = W) when Rate > 0 ->
    %% From now on node N's clock runs at Rate: its timers, its suspicion
    %% and its lease take 1000 / Rate times as long in real time.
    Nd = maps:get(N, Nodes),
    W#{rates := Rates#{N := Rate}, nodes := Nodes#{N := Nd#{clock := {maps:get(now, W), local(N, W), Rate}}}};
fault(_Cmd, W) -> W.

link(A, B) when A < B -> {A, B};
link(A, B) -> {B, A}.

connected(A, A, _W) -> true;
connected(A, B, #{cut := Cut}) -> not lists:member(link(A, B), Cut).

running(N, #{nodes := Nodes}) -> maps:get(status, maps:get(N, Nodes)) =:= up.

%% Time goes by in steps of at most a heartbeat: messages due, timers due,
%% then every running node's failure detection.
advance(Ms, #{now := Now} = W) when Ms =< 0 -> W#{now := Now};
advance(Ms, #{now := Now} = W) ->
    D = min(Ms, ?HB),
    W1 = deliver_until(Now + D, W#{now := Now + D}),
    W2 = fire_timers(W1),
    W3 = lists:foldl(fun detect/2, W2, maps:get(names, W2)),
    advance(Ms - D, W3).

%% ---------------------------------------------------------------------------
%% Messages
%% ---------------------------------------------------------------------------

%% To is {node, N} (its voter) or {inst, Ref}.
send(FromNode, To, Msg, W) ->
    ToNode = to_node(To, W),
    case ToNode =/= undefined andalso connected(FromNode, ToNode, W) of
        true ->
            #{seq := S} = W,
            W1 = enqueue_at(maps:get(now, W) + ?LATENCY, To, Msg, W),
            W1#{senders => (maps:get(senders, W, #{}))#{S => FromNode}};
        false ->
            W
    end.

%% Erlang keeps the order of messages between two processes: nothing sent
%% to a node overtakes what was sent to it before (a delay delays the rest).
enqueue_at(At0, To, Msg, #{msgs := Ms, seq := S} = W) ->
    Floor = maps:get(floor, W, #{}),
    Node = to_node(To, W),
    At = max(At0, maps:get(Node, Floor, 0)),
    W#{msgs := lists:sort([{At, S, To, Msg} | Ms]), seq := S + 1, floor => Floor#{Node => At}}.

to_node({node, N}, _W) -> N;
to_node({inst, Ref}, #{insts := Insts}) ->
    case Insts of
        #{Ref := #{node := N}} -> N;
        #{} -> undefined
    end.

deliver_until(T, #{msgs := [{At, S, To, Msg} | Rest]} = W) when At =< T ->
    {From, Senders} = take_sender(S, W),
    W1 = W#{msgs := Rest, senders => Senders},
    case to_node(To, W1) of
        undefined ->
            deliver_until(T, W1);
        N ->
            case maps:get(status, maps:get(N, maps:get(nodes, W1))) of
                up -> deliver_until(T, receive_msg(To, Msg, heard_by(N, From, W1)));
                paused -> deliver_until(T, requeue(To, Msg, W1));
                down -> deliver_until(T, W1)
            end
    end;
deliver_until(_T, W) ->
    W.

take_sender(S, W) ->
    Senders = maps:get(senders, W, #{}),
    case maps:take(S, Senders) of
        {From, Senders1} -> {From, Senders1};
        error -> {undefined, Senders}
    end.

%% A message from another node comes over the connection its heartbeats
%% use, after those sent before it: its node counts as heard now, even
%% when it was delayed and its node is down since (evatar_cluster stamps a
%% heartbeat when it arrives).
heard_by(N, From, #{nodes := Nodes} = W) when From =/= undefined, From =/= N ->
    #{heard := Heard} = Nd = maps:get(N, Nodes),
    Now = local(N, W),
    At = case maps:get(From, Heard) of
             undefined -> Now;
             T -> max(Now, T)
         end,
    W#{nodes := Nodes#{N := Nd#{heard := Heard#{From := At}}}};
heard_by(_N, _From, W) ->
    W.

%% A paused node's messages wait for it (its sockets buffer them).
requeue(To, Msg, #{paused_q := Q} = W) -> W#{paused_q := Q ++ [{To, Msg}]};
requeue(To, Msg, W) -> W#{paused_q => [{To, Msg}]}.

%% ---------------------------------------------------------------------------
%% Failure detection: each node's view, as evatar_cluster keeps it
%% ---------------------------------------------------------------------------

%% In node N's time; `undefined': not heard since its nodedown.
detect(N, #{nodes := Nodes, names := Names} = W) ->
    case maps:get(N, Nodes) of
        #{status := up, heard := Heard0, alive := Alive0} = Nd ->
            Now = local(N, W),
            Heard = maps:map(fun(M, T) ->
                                     case M =:= N orelse (running(M, W) andalso connected(N, M, W)) of
                                         true -> Now;
                                         false -> T
                                     end
                             end, Heard0),
            Alive = maps:map(fun(M, T) -> M =:= N orelse within(Now, T, ?SUSPECT) end, Heard),
            Q = evatar_ha_membership:majority(Names, [M || {M, T} <- maps:to_list(Heard),
                                                     within(Now, T, ?LEASE)]),
            W1 = W#{nodes := Nodes#{N := Nd#{heard := Heard, alive := Alive, quorum := Q}}},
            Lost = [M || M <- Names, maps:get(M, Alive0), not maps:get(M, Alive)],
            Back = [M || M <- Names, not maps:get(M, Alive0), maps:get(M, Alive)],
            W2 = lists:foldl(fun(M, Acc) -> inst_event(N, {node_suspected, M}, Acc) end, W1, Lost),
            W3 = lists:foldl(fun(M, Acc) -> node_back(N, M, Acc) end, W2, Back),
            case Q =:= maps:get(quorum, Nd) of
                true -> W3;
                false -> inst_event(N, {quorum, Q}, W3)
            end;
        #{} ->
            W
    end.

%% A node heard again gets this node's inventory: instances compare epochs.
node_back(N, M, W) ->
    W1 = inst_event(N, {node_alive, M}, W),
    case inst_on(N, W1) of
        undefined -> W1;
        #{ref := Ref, role := Role, epoch := E} ->
            %% The registry's role: a handover under way is the active.
            Shown = case Role of
                        handing_over -> active;
                        _ -> Role
                    end,
            send(N, {node, M}, {inventory, Ref, Shown, E}, W1)
    end.

heard_within(N, M, Ms, #{nodes := Nodes} = W) ->
    within(local(N, W), maps:get(M, maps:get(heard, maps:get(N, Nodes))), Ms).

within(_Now, undefined, _Ms) -> false;
within(Now, T, Ms) -> Now - T =< Ms.

majority_now(N, #{names := Names} = W) ->
    evatar_ha_membership:majority(Names, [M || M <- Names, heard_within(N, M, ?LEASE, W)]).

pause(N, #{nodes := Nodes} = W) ->
    case maps:get(N, Nodes) of
        #{status := up} = Nd -> W#{nodes := Nodes#{N := Nd#{status := paused, paused_at := local(N, W)}}};
        #{} -> W
    end.

%% The node finds it was paused itself: its peers' silence meanwhile says
%% nothing about them (evatar_ha_membership:discount/3), and an active asks the
%% cluster again (evatar_ha_core's `paused').
resume(N, #{nodes := Nodes} = W) ->
    case maps:get(N, Nodes) of
        #{status := paused, paused_at := At, heard := Heard} = Nd ->
            Now = local(N, W),
            Paused = Now - At,
            Heard1 = maps:map(fun(_, undefined) -> undefined;
                                 (_, T) -> evatar_ha_membership:discount(T, Paused, Now)
                              end, Heard),
            W1 = W#{nodes := Nodes#{N := Nd#{status := up, heard := Heard1}}},
            Q = maps:get(paused_q, W1, []),
            {Mine, Others} = lists:partition(fun({To, _}) -> to_node(To, W1) =:= N end, Q),
            W2 = lists:foldl(fun({To, Msg}, Acc) -> receive_msg(To, Msg, Acc) end,
                             W1#{paused_q => Others}, Mine),
            case Paused > evatar_ha_membership:stall_ms(?HB, ?LEASE) of
                true -> inst_event(N, stalled, W2);
                false -> W2
            end;
        #{} ->
            W
    end.

%% kill -9 of the node: its instance and its memory go; its disc, with the
%% promises its voter gave, stays.
crash(N, #{nodes := Nodes, names := Names} = W) ->
    Down = [M || M <- Names, maps:get(status, maps:get(M, Nodes)) =:= down],
    case maps:get(N, Nodes) of
        #{status := S} = Nd when S =/= down, Down =:= [] ->
            W0 = W#{nodes := Nodes#{N := Nd#{status := down, down_at := maps:get(now, W),
                                             voter := lost}}},
            W1 = case Nd of
                     #{inst := undefined} -> W0;
                     #{inst := Ref} -> kill(Ref, W0)
                 end,
            %% Its connections close: every other node in touch sees
            %% nodedown (a paused one when it runs again); one across a cut
            %% sees silence, and nodedown only when the node's next
            %% incarnation connects ({@link restart/2}).
            W2 = lists:foldl(fun(M, Acc) ->
                                     case connected(N, M, Acc) of
                                         true -> enqueue_at(maps:get(now, Acc), {node, M},
                                                            {nodedown, N}, Acc);
                                         false -> pend(N, {node, M}, {nodedown, N}, Acc)
                                     end
                             end, W1, [M || M <- Names, M =/= N]),
            Nodes1 = maps:get(nodes, W2),
            W2#{nodes := Nodes1#{N := (maps:get(N, Nodes1))#{inst := undefined}},
                paused_q => [{To, M} || {To, M} <- maps:get(paused_q, W1, []),
                                        to_node(To, W1) =/= undefined]};
        #{} ->
            W
    end.

%% A node boots in a second at least: the others have suspected it by then.
%% Its voter reads back what it promised (evatar_ha_promises).
%% Its new incarnation connects to the others, which drop the old,
%% silent, connection first: nodedown and the monitors' DOWN that a cut held
%% back come now.
restart(N, #{nodes := Nodes, names := Names, now := Now} = W) ->
    case maps:get(N, Nodes) of
        #{status := down, down_at := At, disk := Disk} when Now - At >= 1000 ->
            {Mine, Others} = lists:partition(fun({M, _, _}) -> M =:= N end,
                                             maps:get(pending, W, [])),
            W1 = lists:foldl(fun({_, To, Msg}, Acc) -> enqueue_at(Now, To, Msg, Acc) end,
                             W#{pending => Others}, Mine),
            %% A new VM: its monotonic clock starts at another offset.
            W2 = W1#{boots := maps:get(boots, W1) + 1},
            W2#{nodes := Nodes#{N := (node0(Names, clock0(N, W2)))#{voter := Disk, disk := Disk}}};
        #{} ->
            W
    end.

%% What a node's end says to the others once they are in touch again: a
%% restart of that node ({@link restart/2}) or, for a process that died on a
%% running node, the heal.
pend(N, To, Msg, W) ->
    W#{pending => maps:get(pending, W, []) ++ [{N, To, Msg}]}.

unpend_running(#{now := Now} = W) ->
    {Due, Keep} = lists:partition(fun({M, To, _}) ->
                                          running(M, W) andalso to_node(To, W) =/= undefined
                                              andalso connected(M, to_node(To, W), W)
                                  end, maps:get(pending, W, [])),
    lists:foldl(fun({_, To, Msg}, Acc) -> enqueue_at(Now + ?LATENCY, To, Msg, Acc) end,
                W#{pending => Keep}, Due).

%% ---------------------------------------------------------------------------
%% Instances
%% ---------------------------------------------------------------------------

inst_on(N, #{nodes := Nodes, insts := Insts}) ->
    case maps:get(inst, maps:get(N, Nodes)) of
        undefined -> undefined;
        Ref -> maps:get(Ref, Insts)
    end.

new_inst(N, W) ->
    #{next_ref := R, nodes := Nodes, insts := Insts} = W,
    Ref = {N, R},
    Inst = evatar_ha_instance:new(p, Ref, maps:get(config, W)),
    I = sync(#{ref => Ref, node => N, inst => Inst, timers => #{}, mons => #{}, postponed => []}),
    {I, W#{next_ref := R + 1, insts := Insts#{Ref => I},
           nodes := Nodes#{N := (maps:get(N, Nodes))#{inst := Ref}}}}.

put_inst(#{ref := Ref} = I, #{insts := Insts} = W) -> W#{insts := Insts#{Ref => I}}.

kill(Ref, #{insts := Insts, nodes := Nodes} = W) ->
    case Insts of
        #{Ref := #{node := N}} ->
            Nd = maps:get(N, Nodes),
            Nodes1 = case Nd of
                         #{inst := Ref} -> Nodes#{N := Nd#{inst := undefined}};
                         #{} -> Nodes
                     end,
            W1 = W#{insts := maps:remove(Ref, Insts), nodes := Nodes1},
            %% Monitors: the other instances on running nodes see the
            %% process die (a crashed node's look like noconnection).
            Why = case maps:get(status, Nd) of
                      down -> noconnection;
                      _ -> killed
                  end,
            lists:foldl(fun(#{ref := R2, node := N2, mons := Mons}, Acc) ->
                                %% Across a silent cut nothing comes: the
                                %% others learn it by suspicion, and the
                                %% monitors fire when the connection is
                                %% back or replaced (pend/4); else after
                                %% whatever it sent before.
                                lists:foldl(
                                  fun({Which, _}, A2) ->
                                          Down = {down, Which, Why, Ref},
                                          case connected(N, N2, A2) of
                                              true -> down_later(R2, Down, A2);
                                              false -> pend(N, {inst, R2}, {event, Down}, A2)
                                          end
                                  end, Acc, [M || {_, R3} = M <- maps:to_list(Mons), R3 =:= Ref])
                        end, W1, maps:values(maps:get(insts, W1)));
        #{} ->
            W
    end.

down_later(Ref, Event, #{now := Now} = W) ->
    enqueue_at(Now + ?LATENCY, {inst, Ref}, {event, Event}, W).

start_active(N, W) ->
    {#{ref := Ref} = I, W1} = new_inst(N, W),
    ensure_clients(Ref, handle({start, create, none}, I, W1)).

%% The catalogue of node N restores the pairing: N runs no instance of it
%% and, from its view, no connected node does (evatar_catalogue). Views
%% differ after a partial restart: two nodes may both do it, and one may
%% while an instance runs where it does not look.
restore(N, W) ->
    case running(N, W) andalso inst_on(N, W) of
        undefined ->
            {I, W1} = new_inst(N, W),
            handle({start, restore, none}, I, W1);
        _ ->
            W
    end.

inst_event(N, Event, W) ->
    case running(N, W) andalso inst_on(N, W) of
        #{ref := Ref} -> inst_event_ref(Ref, Event, W);
        _ -> W
    end.

inst_event_ref(Ref, Event, #{insts := Insts} = W) ->
    case Insts of
        #{Ref := #{node := N} = I} ->
            case maps:get(status, maps:get(N, maps:get(nodes, W))) of
                up -> handle(Event, I, W);
                paused -> requeue({inst, Ref}, {event, Event}, W);
                down -> W
            end;
        #{} ->
            W
    end.

receive_msg({node, N}, Msg, W) -> voter(N, Msg, W);
receive_msg({inst, Ref}, {event, Event}, W) -> inst_event_ref(Ref, Event, W);
receive_msg({inst, Ref}, Msg, W) -> inst_event_ref(Ref, {msg, Msg}, W).

%% A timer is due when its node's clock reads its time.
fire_timers(#{insts := Insts} = W) ->
    lists:foldl(
      fun(#{ref := Ref, timers := Ts, node := N}, Acc) ->
              Due = case running(N, Acc) of
                        true -> Now = local(N, Acc),
                                lists:sort([{At, K} || {K, At} <- maps:to_list(Ts), At =< Now]);
                        false -> []  % a paused node's clock stands still
                    end,
              lists:foldl(fun({_, K}, A2) ->
                                  case maps:get(insts, A2) of
                                      #{Ref := #{timers := #{K := _} = T2} = I2} ->
                                          A3 = put_inst(I2#{timers := maps:remove(K, T2)}, A2),
                                          inst_event_ref(Ref, {timeout, K}, A3);
                                      #{} -> A2
                                  end
                          end, Acc, Due)
      end, W, maps:values(Insts)).

%% The voters: evatar_cluster's answers, by evatar_ha_core:answer/2's
%% effects: a changed record is on the node's disc before the reply goes.
voter(N, {vote, Ec, Cand, Claim, Active, Dead}, #{nodes := Nodes} = W) ->
    #{voter := Rec} = maps:get(N, Nodes),
    Blocked = lists:any(fun(P) -> serving_as_seen(N, P, W) end,
                        evatar_ha_core:blockers(Rec, Cand, Active, Dead)),
    voter_effects(evatar_ha_core:answer({vote, Ec, Cand, Claim, Blocked}, Rec), N,
                  fun(Result) -> {Cand, {vote_reply, p, Ec, N, Result}} end, W);
voter(N, {restore_vote, Ec, Cand, NoneOn}, #{nodes := Nodes} = W) ->
    #{voter := Rec} = maps:get(N, Nodes),
    Local = case inst_on(N, W) of
                undefined -> undefined;
                #{ref := Ref, role := Role} -> {Ref, Role}
            end,
    Blocked = lists:any(fun(P) -> serving_as_seen(N, P, W) end,
                        evatar_ha_core:restore_blockers(Rec, Cand, NoneOn,
                                                        fun evatar_ha_instance:node_of/1, Local)),
    voter_effects(evatar_ha_core:answer({restore_vote, Ec, Cand, Blocked}, Rec), N,
                  fun(Result) -> {Cand, {vote_reply, p, Ec, N, Result}} end, W);
voter(N, {ask, From}, W) ->
    %% evatar_cluster's answer: what this node runs of the pairing.
    Info = case inst_on(N, W) of
               undefined -> none;
               #{ref := Ref, role := Role, epoch := E, inst := Inst} ->
                   Shown = case Role of
                               handing_over -> active;
                               _ -> Role
                           end,
                   Peer = case Shown of
                              standby -> evatar_ha_instance:active(Inst);
                              _ -> evatar_ha_instance:standby(Inst)
                          end,
                   #{pid => Ref, role => Shown, epoch => E, peer => Peer}
           end,
    send(N, {inst, From}, {event, {instance, N, Info}}, W);
voter(N, {register, {E, Seq} = Claim, From}, #{nodes := Nodes} = W) ->
    #{voter := Rec} = maps:get(N, Nodes),
    voter_effects(evatar_ha_core:answer({register, E, Seq, From}, Rec), N,
                  fun(Result) -> {From, {register_reply, p, Claim, N, Result}} end, W);
voter(N, {nodedown, M}, #{nodes := Nodes} = W) ->
    #{alive := Alive, heard := Heard} = Nd = maps:get(N, Nodes),
    W1 = W#{nodes := Nodes#{N := Nd#{alive := Alive#{M := false}, heard := Heard#{M := undefined}}}},
    case maps:get(M, Alive) of
        true -> inst_event(N, {node_suspected, M}, W1);
        false -> W1
    end;
voter(N, {inventory, Ref, Role, E}, W) ->
    inst_event(N, {msg, {peer_instance, Ref, Role, E}}, W);
voter(N, {start_standby, Active}, #{insts := Insts} = W) ->
    case inst_on(N, W) of
        undefined when is_map_key(Active, Insts) ->
            {I, W1} = new_inst(N, W),
            handle({start, {standby_for, Active}, none}, I, W1);
        #{ref := Ref} when Ref =/= Active ->
            %% evatar_cluster tells the instance it holds about the active
            %% asking (the two compare epochs).
            case Insts of
                #{Active := #{role := Role, epoch := E}} ->
                    inst_event(N, {msg, {peer_instance, Active, Role, E}}, W);
                #{} ->
                    W
            end;
        _ ->
            W
    end.

voter_effects([{persist, R} | Rest], N, Reply, #{nodes := Nodes} = W) ->
    Nd = maps:get(N, Nodes),
    voter_effects(Rest, N, Reply, W#{nodes := Nodes#{N := Nd#{voter := R, disk := R}}});
voter_effects([{reply, Result}], N, Reply, W) ->
    {To, Msg} = Reply(Result),
    send(N, {inst, To}, Msg, W).

serving_as_seen(N, {M, _} = Ref, #{insts := Insts} = W) ->
    case M =:= N of
        true -> maps:is_key(Ref, Insts);
        false -> heard_within(N, M, ?SUSPECT, W)
    end.

%% ---------------------------------------------------------------------------
%% One instance: evatar_ha_instance decides (the code the node runs); this
%% executes its effects on the simulated world, as evatar_pairing does on
%% processes
%% ---------------------------------------------------------------------------

handle({down, Which, Why, Ref}, #{mons := Mons} = I, W) ->
    case Mons of
        #{Which := Ref} -> handle({down, Which, Why}, I#{mons := maps:remove(Which, Mons)}, W);
        #{} -> put_inst(I, W)  % demonitored meanwhile: its DOWN never comes
    end;
handle(Event, #{inst := Inst, ref := Ref} = I, W0) ->
    W = case Event of
            {msg, {confirm, Sb, _, _}} when Sb =:= map_get(standby, I) -> covered(I, W0);
            _ -> W0
        end,
    {Inst1, Effects} = evatar_ha_instance:handle(ha_event(Event), view(I, W), Inst),
    W1 = ha_effects(Effects, Event, sync(I#{inst := Inst1}), W),
    %% As gen_statem does: postponed events come again once the state changed.
    case maps:get(insts, W1) of
        #{Ref := #{inst := Inst2, postponed := [_ | _] = P} = I2} ->
            case evatar_ha_instance:role(Inst2) =/= evatar_ha_instance:role(Inst) of
                true -> lists:foldl(fun(E, Acc) -> inst_event_ref(Ref, E, Acc) end,
                                    put_inst(I2#{postponed := []}, W1), lists:reverse(P));
                false -> W1
            end;
        #{} ->
            W1
    end.

ha_event({timeout, _} = E) -> E;
ha_event({msg, _} = E) -> E;
ha_event({start, _, _} = E) -> E;
ha_event({instance, _, _} = E) -> E;
ha_event({down, _, _} = E) -> E;
ha_event(ClusterEvent) -> {cluster, ClusterEvent}.

%% What the instance sees: this node's view of the cluster (evatar_cluster's),
%% the time of the rules (the wall clock every node shares: simulated real
%% time) and the clients, who reach every node.
view(#{node := N}, #{names := Names, nodes := Nodes} = W) ->
    Alive = maps:get(alive, maps:get(N, Nodes)),
    #{nodes => Names, heartbeat_ms => ?HB, suspect_ms => ?SUSPECT, self => N,
      now => maps:get(now, W), conns => conns(),
      alive => [M || M <- Names, M =:= N orelse maps:get(M, Alive)],
      majority => majority_now(N, W), heard => [M || M <- Names, heard_within(N, M, ?LEASE, W)],
      standby_opt => true, client_ack_timeout => ?CLIENT_ACK_TIMEOUT,
      handover_on_silent_link => true}.

conns() -> #{?VA => sender, ?AV => receiver}.

%% The role, core, peers and epoch, as the checks read them.
sync(#{inst := Inst} = I) ->
    I#{role => evatar_ha_instance:role(Inst), core => evatar_ha_instance:core(Inst),
       active => evatar_ha_instance:active(Inst), standby => evatar_ha_instance:standby(Inst),
       epoch => evatar_ha_instance:epoch(Inst)}.

ha_effects([{stop, _} | _], _Event, I, W) ->
    kill(ref(I), put_inst(I, W));
ha_effects([postpone | Rest], Event, #{postponed := P} = I, W) ->
    ha_effects(Rest, Event, I#{postponed := [Event | P]}, W);
ha_effects([E | Rest], Event, I, W) ->
    W1 = ha_effect(E, I, put_inst(I, W)),
    ha_effects(Rest, Event, maps:get(ref(I), maps:get(insts, W1)), W1);
ha_effects([], _Event, I, W) ->
    put_inst(I, W).

ha_effect({send, To, Msg}, I, W) ->
    send(node_of(I), {inst, To}, peer_msg(Msg, I), W);
ha_effect({to_node, M, {start_standby, _Config}}, I, W) ->
    send(node_of(I), {node, M}, {start_standby, ref(I)}, W);
ha_effect({to_node, M, {vote, Ec, Claim, Active, Dead}}, I, W) ->
    send(node_of(I), {node, M}, {vote, Ec, ref(I), Claim, Active, Dead}, W);
ha_effect({to_node, M, {restore_vote, Ec, NoneOn}}, I, W) ->
    send(node_of(I), {node, M}, {restore_vote, Ec, ref(I), NoneOn}, W);
ha_effect({to_node, M, ask}, I, W) ->
    send(node_of(I), {node, M}, {ask, ref(I)}, W);
ha_effect({to_node, M, {register, Claim}}, I, W) ->
    send(node_of(I), {node, M}, {register, Claim, ref(I)}, W);
ha_effect({monitor, Which, none}, #{mons := Mons} = I, W) ->
    put_inst(I#{mons := maps:remove(Which, Mons)}, W);
ha_effect({monitor, Which, To}, #{mons := Mons} = I, #{insts := Insts} = W) ->
    W1 = put_inst(I#{mons := Mons#{Which => To}}, W),
    case Insts of
        #{To := _} -> W1;
        #{} -> down_later(ref(I), {down, Which, noproc, To}, W1)  % gone already
    end;
ha_effect({timer, K, Ms}, I, W) ->
    put_inst(timer(K, Ms, I, W), W);
ha_effect({ensure_timer, K, Ms}, #{timers := Ts} = I, W) ->
    case Ts of
        #{K := _} -> W;
        #{} -> put_inst(timer(K, Ms, I, W), W)
    end;
ha_effect({cancel_timer, K}, #{timers := Ts} = I, W) ->
    put_inst(I#{timers := maps:remove(K, Ts)}, W);
ha_effect(cancel_rule_timers, #{timers := Ts} = I, W) ->
    put_inst(I#{timers := maps:filter(fun(K, _) -> element(1, K) =:= ha end, Ts)}, W);
ha_effect({to_client, ?AV, {signal, Signal}}, I, W) ->
    to_receiver(Signal, I, W);
ha_effect({to_client, {conn, receiver}, {signal, Signal}}, I, W) ->
    to_receiver(Signal, I, W);
ha_effect({to_client, ?VA, {ack, Sid}}, #{standby := S} = I, W) ->
    %% Told without a standby that holds it: degraded, not covered by the
    %% guarantee until a standby is synced again.
    Acked = binary_to_integer(Sid),
    W1 = case S =:= undefined orelse maps:get(faults, W, 0) >= 2 of
             true -> degrade(Acked, W);
             false -> W
         end,
    to_sender(Acked, I, W1);
ha_effect({stepped, Event, _, _}, I, W) ->
    won(Event, ref(I), W);
ha_effect(_NothingHere, _I, W) ->
    %% Logs, metrics, the registry, replies, Binding reports and drops are
    %% not modelled: a client reaches whichever instance serves on a node.
    W.

%% evatar_ha_proto_v1's messages, with the sender and its epoch.
peer_msg({offer, V}, I) -> {offer, ref(I), V};
peer_msg(dismiss, I) -> {dismiss, ref(I)};
peer_msg({resync, V}, I) -> {resync, ref(I), V};
peer_msg({confirm, V}, #{epoch := E} = I) -> {confirm, ref(I), E, V};
peer_msg({stale, E}, I) -> {stale, ref(I), E};
peer_msg({handover, V}, #{epoch := E} = I) -> {handover, ref(I), E, V};
peer_msg({handover_done, Ec, Claim}, I) -> {handover_done, ref(I), Ec, Claim};
peer_msg({events, Events}, #{epoch := E} = I) -> {events, ref(I), E, Events};
peer_msg({snapshot, V, State, Claim}, #{epoch := E} = I) -> {snapshot, ref(I), E, V, State, Claim}.

%% The standby confirms (what it holds is released next). A synced standby
%% (running, in touch, not electing) holds everything applied before:
%% covered again, and one failure may come again.
covered(#{standby := S} = I, #{sender := Snd} = W) ->
    A = applied(I),
    Covered = [Sid || {Sid, _} <- A],
    Settled = case maps:get(insts, W) of
                  #{S := #{role := standby, core := SCore}} -> not evatar_ha_core:electing(SCore);
                  #{} -> false
              end,
    Faults = case Settled andalso connected(node_of(I), element(1, S), W)
                 andalso running(element(1, S), W) of
                 true -> 0;
                 false -> maps:get(faults, W, 0)
             end,
    {Degraded, W1} = case Faults =:= 0 of
                         true -> {maps:get(degraded, Snd) -- Covered,
                               excuse([Sid || {Sid, _} <- A, lists:member(Sid, maps:get(degraded, Snd))],
                                      A, W)};
                         false -> {maps:get(degraded, Snd), W}
                     end,
    W1#{sender := Snd#{degraded := Degraded}, faults => Faults}.

%% Covered again protects a signal from now on, not backwards: the
%% routings it got while degraded (outside the guarantee, docs/ha-design.md
%% section 9: after a second failure, an instance that took over without it
%% routes it again when it is resent) and the one in the history now
%% covered are excused; any other routing it gets from now on is routed
%% twice.
excuse(Sids, Applied, #{receiver := #{got := Got, excused := Ex} = R} = W) ->
    Ex1 = lists:foldl(fun(Sid, Acc) ->
                              {Sid, Route} = lists:keyfind(Sid, 1, Applied),
                              Acc#{Sid => lists:usort([Route | maps:get(Sid, Got, [])]
                                                      ++ maps:get(Sid, Acc, []))}
                      end, Ex, Sids),
    W#{receiver := R#{excused := Ex1}}.

timer(K, Ms, #{timers := Ts, node := N} = I, W) ->
    I#{timers := Ts#{K => local(N, W) + Ms}}.

ref(#{ref := R}) -> R.
node_of(#{node := N}) -> N.

%% ---------------------------------------------------------------------------
%% The clients, through the pairing's rules
%% ---------------------------------------------------------------------------

%% The rules' options: credentials checked before the event (a join
%% carries the verdict), sessions never given up while the model runs, and
%% windows that hold every signal of a run (the checks read them).
config() ->
    {ok, C} = evatar_pairing_logic:config(#{agent_credential => <<"ca">>,
                                            avatar_credential => <<"cv">>,
                                            resume_timeout => 4294967295,
                                            dedup_window => 1048576,
                                            max_unacked_out => 1048576}),
    C.

entry(Cat, Type) -> #{category => Cat, type => Type, parameters => []}.

description(agent) ->
    #{entity_id => ?VA, api_name => <<"VA">>, entity_type => agent, context => <<>>,
      components => [#{id => <<"Emu">>, services => [entry(<<"A">>, <<"Feedback">>)],
                       consumes => [entry(<<"A">>, <<"On">>)]}]};
description(avatar) ->
    #{entity_id => ?AV, api_name => <<"AV">>, entity_type => avatar, context => <<>>,
      components => [#{id => <<"Light">>, services => [entry(<<"A">>, <<"On">>)],
                       consumes => []}]}.

signal(Sid) ->
    #{id => integer_to_binary(Sid), context => request_no_feedback, sender => <<"Emu">>,
      receiver => <<"Light">>, in_reply_to => undefined, timestamp => 1, seq => undefined,
      epoch => undefined, body => entry(<<"A">>, <<"On">>)}.

%% Both clients join the active instance `Ref' and describe themselves if
%% its rules do not know them (a new pairing, or one restored afresh), as
%% a client told its session was not resumed does.
ensure_clients(Ref, W) ->
    lists:foldl(fun({Role, Id, Session}, Acc) ->
                        case maps:get(insts, Acc) of
                            #{Ref := #{role := active, inst := Inst} = I} ->
                                Known = evatar_pairing_logic:entity_ids(
                                          evatar_ha_instance:logic(Inst)),
                                case lists:member(Id, Known) of
                                    true -> Acc;
                                    false ->
                                        Acc1 = client_event({join, Role, Id, authenticated, Session},
                                                            I, Acc),
                                        client_event({describe, Id, description(Role)},
                                                     maps:get(Ref, maps:get(insts, Acc1)), Acc1)
                                end;
                            #{} ->
                                Acc
                        end
                end, W, [{agent, ?VA, <<"sa">>}, {avatar, ?AV, <<"sv">>}]).

%% A client's event on the active: its effects, then the batch flushed at
%% once (the mailbox of a simulated instance is always empty).
client_event(Event, #{inst := Inst} = I, W) ->
    {_Reply, Inst1, Effects} = evatar_ha_instance:rules(Event, #{now => maps:get(now, W),
                                                                 conns => conns()}, Inst),
    W1 = ha_effects(Effects, Event, sync(I#{inst := Inst1}), W),
    #{inst := Inst2} = I2 = maps:get(ref(I), maps:get(insts, W1)),
    {Inst3, Flush} = evatar_ha_instance:flush(Inst2),
    ha_effects(Flush, Event, sync(I2#{inst := Inst3}), W1).

%% @doc What an instance's rules hold: each signal accepted from the
%% sender, with its routing to the receiver (epoch and Sequence, `none'
%% if it was not routed).
-spec applied(map()) -> [{pos_integer(), {pos_integer(), pos_integer()} | none}].
applied(#{inst := Inst}) ->
    case evatar_ha_instance:logic(Inst) of
        undefined ->
            [];
        L ->
            Routes = maps:from_list([{binary_to_integer(Id), {E, Seq}}
                                     || #{id := Id, epoch := E, seq := Seq}
                                            <- evatar_pairing_logic:unacked(L, ?AV)]),
            [{Sid, maps:get(Sid, Routes, none)}
             || Sid <- [binary_to_integer(Id) || Id <- evatar_pairing_logic:accepted_ids(L, ?VA)]]
    end.

%% Who won each epoch (a takeover or a re-election), for check/1.
won({Why, Ec}, Ref, W) when Why =:= takeover; Why =:= reelected ->
    Winners = maps:get(winners, W, #{}),
    W#{winners => Winners#{Ec => lists:usort([Ref | maps:get(Ec, Winners, [])])}};
won(_Event, _Ref, W) ->
    W.

degrade(Sid, #{sender := #{sent := Sent, degraded := D} = Snd} = W) ->
    W#{sender := Snd#{degraded := lists:usort([X || X <- Sent, X =< Sid] ++ D)}}.

%% Clients fence by epoch: nothing from an epoch lower than the highest seen.
to_receiver(#{id := Id, epoch := SE, seq := Seq}, #{epoch := E},
            #{receiver := #{got := Got, epoch := Seen} = R} = W) ->
    Sid = binary_to_integer(Id),
    Route = {SE, Seq},
    case E >= Seen of
        true ->
            Routes = lists:usort([Route | maps:get(Sid, Got, [])]),
            W#{receiver := R#{got := Got#{Sid => Routes}, epoch := E}};
        false ->
            W
    end.

to_sender(Sid, #{epoch := E}, #{sender := #{sent := Sent, acked := Acked, epoch := Seen} = S} = W) ->
    case E >= Seen of
        true ->
            New = [X || X <- Sent, X =< Sid],
            W#{sender := S#{acked := lists:usort(New ++ Acked), epoch := E,
                            sent := Sent -- New}};
        false ->
            W
    end.

%% The sender resends what it was not told was accepted, then a new one,
%% to the instance serving on node N (if any: else it tries later).
client_send(N, #{sender := #{next := Next, sent := Sent} = Snd} = W) ->
    case running(N, W) andalso inst_on(N, W) of
        #{role := active} ->
            send_sids(N, Sent ++ [Next],
                      W#{sender := Snd#{next := Next + 1, sent := Sent ++ [Next]}});
        _ ->
            W
    end.

%% The sender sends again what it was not told was accepted.
resend(N, #{sender := #{sent := Sent}} = W) ->
    send_sids(N, Sent, W).

send_sids(N, Sids, W) ->
    case running(N, W) andalso inst_on(N, W) of
        #{role := active, ref := Ref} ->
            lists:foldl(fun(Sid, Acc) ->
                                case maps:get(insts, Acc) of
                                    #{Ref := #{role := active} = I} ->
                                        client_event({signal, ?VA, signal(Sid)}, I, Acc);
                                    #{} -> Acc
                                end
                        end, ensure_clients(Ref, W), Sids);
        _ ->
            W
    end.

%% ---------------------------------------------------------------------------
%% Checks
%% ---------------------------------------------------------------------------

%% @doc The instances serving: active and not holding, on a running node.
-spec serving(map()) -> [map()].
serving(#{insts := Insts} = W) ->
    [I || #{role := active, core := Core, node := N} = I <- maps:values(Insts),
          running(N, W), not evatar_ha_core:holding(Core)].

%% @doc The safety checks; a violation is recorded in `violations'.
-spec check(map()) -> map().
check(W0) ->
    check1(W0).

check1(#{insts := Insts, sender := #{acked := Acked, degraded := Degraded},
         receiver := #{got := Got, excused := Excused}} = W) ->
    Live = maps:values(Insts),
    MaxE = lists:max([0 | [E || #{epoch := E} <- Live]]),
    Serving = [I || #{epoch := E} = I <- serving(W), E =:= MaxE],
    Covered = Acked -- Degraded,
    V1 = [{two_serving, [R || #{ref := R} <- Serving]} || length(Serving) > 1],
    Applied = maps:from_list([{R, applied(I)} || #{ref := R} = I <- Live]),
    V2 = [{lost, Sid} || Sid <- Covered,
                         not lists:any(fun(A) -> lists:keymember(Sid, 1, A) end,
                                       maps:values(Applied))],
    V3 = [{lost_by_active, Sid, R} || #{ref := R} <- Serving, A <- [maps:get(R, Applied)],
                                      Sid <- Covered, not lists:keymember(Sid, 1, A)],
    V4 = [{twice, Sid, Routes} || {Sid, Routes} <- maps:to_list(Got), lists:member(Sid, Covered),
                                  routed_twice(Routes, maps:get(Sid, Excused, []))],
    V5 = [{not_serving, maps:get(now, W)} || stuck(W)],
    V6 = [{won_twice, E, Refs} || length(maps:get(names, W)) >= 3,
                                  {E, [_, _ | _] = Refs} <- maps:to_list(maps:get(winners, W, #{}))],
    {V7, W1} = lease(W),
    Seen = maps:get(violations, W1),
    case V1 ++ V2 ++ V3 ++ V4 ++ V5 ++ V7 ++ [V || V <- V6, not lists:member(V, Seen)] of
        [] -> W1;
        Vs -> W1#{violations := Seen ++ Vs}
    end.

%% The lease (docs/ha-design.md section 5): with three nodes, an active cut
%% off has fenced before a majority stops hearing it for suspect_ms and
%% grants the pairing to another, so two instances never serve at once,
%% whatever their epochs, while no more than one failure happened (the
%% `faults' of the guarantee) and no restore from a view that missed an
%% instance holding the pairing's state (not promised: count_fault/3 counts
%% it; an old active, paused with its registration's acceptances in its
%% mailbox, may act on them before it sees it was paused, beside the
%% restored one). It rests on the clocks' drift staying
%% within the bound of the module doc.
lease(#{names := Names} = W) when length(Names) >= 3 ->
    Serving = serving(W),
    Pairs = [{R, E} || #{ref := R, epoch := E} <- Serving],
    case maps:get(faults, W, 0) < 2 andalso length(Serving) > 1
        andalso not maps:get(restored_wrong, W, false) of
        false -> {[], W};
        true ->
            {[{lease_overlap, Pairs}], W}
    end;
lease(W) ->
    {[], W}.

%% A signal never degraded gets one routing; one covered again gets none
%% but those excused when it was (excuse/3).
routed_twice(Routes, []) -> length(Routes) > 1;
routed_twice(Routes, Excused) -> Routes -- Excused =/= [].

%% Liveness while a fault lasts: once nothing changed for 2 s, an instance
%% on a node that hears a majority serves (it, or another one, took over).
stuck(#{now := Now, last_change := T, names := Names, nodes := Nodes} = W) when Now - T >= 2000 ->
    WithMajority = [N || N <- Names, running(N, W), maps:get(quorum, maps:get(N, Nodes)),
                         case inst_on(N, W) of
                             #{role := starting} -> false;
                             undefined -> false;
                             _ -> true
                         end],
    WithMajority =/= [] andalso serving(W) =:= [];
stuck(_W) ->
    false.

%% @doc Heals everything, lets time run, and says whether some instance
%% serves and takes a signal.
-spec settle(map()) -> {boolean(), map()}.
settle(#{names := Names} = W0) ->
    W1 = lists:foldl(fun(N, Acc) -> resume(N, restart(N, Acc)) end,
                     advance(1000, step(heal, W0)), Names),
    W2 = advance(3000, W1),
    W3 = lists:foldl(fun(N, Acc) -> client_send(N, Acc) end, W2, Names),
    W4 = check(advance(1000, W3)),
    %% An instance left that holds the pairing's state must serve; with none
    %% left (both failed before a standby was synced) the catalogue restores
    %% the pairing afresh, outside this model.
    Holders = [I || #{role := R} = I <- maps:values(maps:get(insts, W4)), R =/= starting],
    {Holders =:= [] orelse serving(W4) =/= [], W4}.

%% @doc Liveness as docs/ha.md section 6 promises it: the faults stop (every
%% link heals, paused nodes run again, and a crashed node boots again or,
%% with `Restart' false, stays down, leaving a majority up); then, within
%% `ServeMs', exactly one instance serves and holds every signal the sender
%% was told was accepted (those the guarantee covers), and a signal sent
%% then is accepted and routed once within `AcceptMs' more (a standby whose
%% snapshot a cut lost is replaced only after its offer times out, 5 x
%% suspect_ms + 2 s). `{ok, Ms}' gives how long after the heal one instance
%% served (`{ok, restored}': none was left, the catalogue restored the
%% pairing afresh, and the restored instance won its election and served
%% within `ServeMs'); `{frozen, Why}' what was missing at the bound.
-spec live(map(), boolean(), {pos_integer(), pos_integer()}) ->
          {{ok, non_neg_integer() | restored} | {frozen, term()}, map()}.
live(#{names := Names} = W0, Restart, {ServeMs, AcceptMs}) ->
    W1 = case Restart of
             true -> advance(1000, W0);  % a node boots in a second at least
             false -> W0
         end,
    W2 = lists:foldl(fun(N, Acc) ->
                             Acc1 = case Restart of
                                        true -> restart(N, Acc);
                                        false -> Acc
                                    end,
                             resume(N, Acc1)
                     end, step(heal, W1), Names),
    T0 = maps:get(now, W2),
    {Served, W3} = until_one_serves(T0 + ServeMs, check(W2)),
    Holders = [I || I <- maps:values(maps:get(insts, W3)), holds_state(I)],
    case Served of
        false when Holders =:= [] ->
            %% Both instances failed before a standby was synced: what they
            %% held is outside the guarantee, and the catalogue of the
            %% first node (the owner) restores the pairing afresh; the
            %% restored instance wins an election, although the voters
            %% remember configurations of the instances gone, and serves.
            %% A standby still starting whose active died refuses a
            %% restore until its offer times out (AcceptMs covers it).
            W4 = restore_somewhere(maps:get(now, W3) + AcceptMs, W3),
            case until_one_serves(maps:get(now, W4) + ServeMs + AcceptMs, check(W4)) of
                {true, W5} -> signal_accepted(restored, AcceptMs, W5);
                {false, W5} -> {{frozen, {restored, [R || #{ref := R} <- serving(W5)]}}, W5}
            end;
        false ->
            {{frozen, {serving, [R || #{ref := R} <- serving(W3)]}}, W3};
        true ->
            signal_accepted(maps:get(now, W3) - T0, AcceptMs, W3)
    end.

%% The owner is the first running node without an instance (one still
%% starting, e.g. a standby whose active died before its snapshot, stops at
%% its offer's timeout, and is waited for).
restore_somewhere(Deadline, #{names := Names, insts := Insts} = W) ->
    Restoring = [I || #{role := fenced, core := C} = I <- maps:values(Insts),
                      evatar_ha_core:restoring(C)],
    case [N || N <- Names, running(N, W), inst_on(N, W) =:= undefined] of
        _ when Restoring =/= [] -> W;  % restored already, before the faults stopped
        [Owner | _] -> restore(Owner, W);
        [] when map_get(now, W) >= Deadline -> W;
        [] -> restore_somewhere(Deadline, check(advance(?HB, W)))
    end.

%% An instance that holds the pairing's state: not one starting, nor a
%% restorer still standing for election (its state is new).
holds_state(#{role := starting}) -> false;
holds_state(#{role := fenced, core := C}) -> not evatar_ha_core:restoring(C);
holds_state(#{}) -> true.

%% Then a signal through every node: the one serving takes it.
signal_accepted(Result, AcceptMs, #{names := Names} = W) ->
    W1 = lists:foldl(fun(N, Acc) -> client_send(N, Acc) end, W, Names),
    case until_accepted(maps:get(now, W1) + AcceptMs, check(advance(?HB, W1))) of
        {true, W2} -> {{ok, Result}, W2};
        {false, W2} -> {{frozen, {after_signal, maps:get(sender, W2)}}, W2}
    end.

%% Whatever the sender sent is accepted (it resends to the node serving,
%% as a client does after a reconnection).
until_accepted(Deadline, #{sender := #{sent := Unacked}} = W) ->
    case Unacked =:= [] andalso one_serves(W) of
        true -> {true, W};
        false when map_get(now, W) >= Deadline -> {false, W};
        false ->
            W1 = case serving(W) of
                     [#{node := N}] when Unacked =/= [] -> resend(N, W);
                     _ -> W
                 end,
            until_accepted(Deadline, check(advance(?HB, W1)))
    end.

until_one_serves(Deadline, W) ->
    case one_serves(W) of
        true -> {true, W};
        false when map_get(now, W) >= Deadline -> {false, W};
        false -> until_one_serves(Deadline, check(advance(min(10, Deadline - map_get(now, W)), W)))
    end.

%% Exactly one instance serves, and it holds every accepted signal that the
%% guarantee covers.
one_serves(#{sender := #{acked := Acked, degraded := Degraded}} = W) ->
    one_holds(serving(W), Acked -- Degraded).

one_holds(Serving, Covered) ->
    case Serving of
        [I] -> A = applied(I),
               [] =:= [Sid || Sid <- Covered, not lists:keymember(Sid, 1, A)];
        _ -> false
    end.
