%% @doc Internal. Cluster membership for high availability: the configured
%% nodes (app env `cluster', or the OS variable `EVATAR_PEERS'), which of
%% them are alive (connected and heard within `suspect_ms'), whether this
%% node hears a majority within `lease_ms', and standby placement.
%%
%% Every `heartbeat_ms' it heartbeats every connected peer and re-evaluates:
%% a peer silent for `suspect_ms' is suspected, one heard again is alive
%% again (and gets this node's inventory, so instances of one pairing on
%% both sides can compare epochs). Changes are broadcast to this node's
%% pairing processes as `{evatar_cluster, Event}'. It is also the only
%% process that connects nodes (`net_kernel:connect_node/1', retried).
%% Distribution's own tick (`net_ticktime', 45-75 s) is far too slow to be
%% relied on. Reads for the pairings go to an ETS table, never to this
%% process. Decisions are in `evatar_ha_membership' (membership) and `evatar_ha_core'
%% (votes and registrations).
%%
%% Every node's instances address it (`evatar_ha_proto_v1'), and it hands
%% on at once what takes time: vote and registration requests to the
%% node's voter (`evatar_ha_voter', which writes promises to disc) and
%% standbys to start to `evatar_ha_starter'. It runs at high priority and
%% does little else, so that a takeover storm (hundreds of elections, a
%% run queue of hundreds of pairing processes) delays neither its
%% heartbeats nor its ticks: a late tick is taken for a pause of the whole
%% node (its actives then ask the cluster again), so it must be late only
%% when the node was.
%%
%% Its evaluation every `heartbeat_ms' runs now through {@link
%% refresh_now/0} (tests, through `evatar:run_now(cluster)'): an evaluation
%% early, which decides as the timed one would (a shorter gap since the
%% last one is never taken for a pause of this node).
-module(evatar_cluster).
-behaviour(gen_server).

-export([start_link/0, opt/1, configured/0, size/0, alive/1, alive_now/1, alive_nodes/0,
         quorum/0, majority_now/0, heard_within/2, heard_after/2,
         place_standby/1, status/0, quorum_size/0, stall_gen/0, unstalled/1, refresh_now/0]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-include_lib("kernel/include/logger.hrl").

-define(TABLE, evatar_cluster_view).
-define(RECONNECT_MS, 500).

-record(s, {nodes :: [node()],
            alive = #{} :: #{node() => true},
            heard = #{} :: #{node() => integer()},
            quorum = true :: boolean(),
            last_tick :: integer(),
            attempts = #{} :: #{node() => integer()}}).

-type event() :: {node_suspected, node()} | {node_down, node()} | {node_alive, node()}
               | {quorum, boolean()} | stalled.
-export_type([event/0]).

%% @doc Starts the membership process, registered as `evatar_cluster'.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    gen_server:start_link({local, ?MODULE}, ?MODULE, [], []).

%% @doc A high-availability setting from the `evatar' application
%% environment, with its default (docs/ha-design.md).
-spec opt(atom()) -> term().
opt(Key) ->
    application:get_env(evatar, Key, default(Key)).

default(heartbeat_ms) -> 50;
default(suspect_ms) -> 250;
default(lease_ms) -> 150;
default(resume_timeout) -> 10000;
default(client_ack_timeout) -> 5000;
default(handover_on_silent_link) -> true;
default(dedup_window) -> 1024;
default(max_unacked_out) -> 8192;
default(standby) -> true.

%% @doc The configured nodes, sorted, this one included.
-spec configured() -> [node()].
configured() ->
    case ets:lookup(?TABLE, configured) of
        [{_, Nodes}] -> Nodes;
        [] -> [node()]
    end.

%% @doc The number of configured nodes.
-spec size() -> pos_integer().
size() -> length(configured()).

%% @doc Whether `Node' is alive as seen from here (this node always is).
-spec alive(node()) -> boolean().
alive(Node) when Node =:= node() -> true;
alive(Node) -> ets:member(?TABLE, {alive, Node}).

%% @doc Whether `Node' is connected and was heard within `suspect_ms', right
%% now ({@link alive/1} is updated once per heartbeat).
-spec alive_now(node()) -> boolean().
alive_now(Node) when Node =:= node() -> true;
alive_now(Node) ->
    lists:member(Node, erlang:nodes()) andalso heard_within(Node, opt(suspect_ms)).

%% @doc This node and every peer alive as seen from here.
-spec alive_nodes() -> [node()].
alive_nodes() ->
    [node() | [N || [N] <- ets:match(?TABLE, {{alive, '$1'}, true})]].

%% @doc Whether this node heard a majority of the configured nodes within
%% the lease.
-spec quorum() -> boolean().
quorum() ->
    case ets:lookup(?TABLE, quorum) of
        [{_, Q}] -> Q;
        [] -> true
    end.

%% @doc Whether this node hears a majority right now: connected nodes heard
%% within the lease, this one included. Decisions to take over or fence use
%% this rather than {@link quorum/0}, which is updated once per heartbeat.
-spec majority_now() -> boolean().
majority_now() ->
    Lease = opt(lease_ms),
    Configured = configured(),
    Connected = erlang:nodes(),
    Heard = [node() | [N || N <- Configured, N =/= node(), lists:member(N, Connected),
                            heard_within(N, Lease)]],
    evatar_ha_membership:majority(Configured, Heard).

%% @doc Whether `Node' was heard within the last `Ms' milliseconds.
-spec heard_within(node(), non_neg_integer()) -> boolean().
heard_within(Node, _Ms) when Node =:= node() -> true;
heard_within(Node, Ms) ->
    case ets:lookup(?TABLE, {heard, Node}) of
        [{_, T}] -> erlang:monotonic_time(millisecond) - T =< Ms;
        [] -> false
    end.

%% @doc Whether `Node' was heard after `SinceMs' (monotonic milliseconds).
-spec heard_after(node(), integer()) -> boolean().
heard_after(Node, _Since) when Node =:= node() -> true;
heard_after(Node, Since) ->
    case ets:lookup(?TABLE, {heard, Node}) of
        [{_, T}] -> T > Since;
        [] -> false
    end.

%% @doc How many nodes must grant a vote or accept a registration.
-spec quorum_size() -> pos_integer().
quorum_size() -> evatar_ha_core:quorum_size(size()).

%% @doc A number that changes each time this node finds it was itself
%% stopped or starved for longer than `suspect_ms' (SIGSTOP, a frozen VM):
%% the others may have given its pairings away meanwhile.
-spec stall_gen() -> non_neg_integer().
stall_gen() ->
    case ets:lookup(?TABLE, stall_gen) of
        [{_, G}] -> G;
        [] -> 0
    end.

%% @doc Whether this node was not stalled since stall generation `Gen' (nor
%% is it now: its last tick is not overdue), as an active that began
%% serving at `Gen' needs to go on.
-spec unstalled(non_neg_integer()) -> boolean().
unstalled(Gen) ->
    Overdue = case ets:lookup(?TABLE, last_tick) of
                  [{_, T}] -> evatar_ha_membership:stalled(
                                T, erlang:monotonic_time(millisecond),
                                evatar_ha_membership:stall_ms(opt(heartbeat_ms), opt(lease_ms))
                                + opt(heartbeat_ms));
                  [] -> false
              end,
    not Overdue andalso stall_gen() =:= Gen.

%% @doc The node where a standby of a pairing active here should go.
-spec place_standby(node() | undefined) -> node() | none.
place_standby(Preferred) ->
    evatar_ha_membership:standby_node(configured(), node(), alive_nodes(), Preferred).

%% @doc For tests: the periodic evaluation now, as its timer would run it
%% (a heartbeat sent to every connected peer; peers heard within
%% `suspect_ms' alive, the others suspected; a reconnection tried; the
%% majority judged), returning once it is done: the view, which the
%% pairings read, is then up to date with what this node has heard.
-spec refresh_now() -> ok.
refresh_now() ->
    gen_server:call(?MODULE, refresh_now, infinity).

%% @doc The cluster as this node sees it.
-spec status() -> #{configured := [node()], up := [node()], suspected := [node()],
                    quorum := boolean()}.
status() ->
    Alive = alive_nodes(),
    Configured = configured(),
    #{configured => Configured, up => lists:sort(Alive),
      suspected => [N || N <- Configured, not lists:member(N, Alive)],
      quorum => quorum()}.

%% ---------------------------------------------------------------------------
%% gen_server
%% ---------------------------------------------------------------------------

%% @private
-spec init([]) -> {ok, #s{}} | {stop, term()}.
init([]) ->
    %% Timings come from the release's environment (EVATAR_HEARTBEAT_MS...):
    %% a node with inconsistent ones does not start, saying which.
    case evatar_ha_membership:check_timings(maps:from_list([{K, opt(K)} || K <- [heartbeat_ms,
                                                                             suspect_ms,
                                                                             lease_ms]])) of
        ok -> init_view();
        {error, Reason} -> {stop, Reason}
    end.

init_view() ->
    _ = ets:new(?TABLE, [named_table, protected, set, {read_concurrency, true}]),
    Nodes = lists:usort([node() | configured_nodes()]),
    true = ets:insert(?TABLE, [{configured, Nodes}, {quorum, true}, {stall_gen, 0},
                               {last_tick, erlang:monotonic_time(millisecond)}]),
    _ = case is_alive() of
            true -> net_kernel:monitor_nodes(true);
            false -> ok
        end,
    %% Ahead of the pairings in the run queue (see the module doc).
    _ = process_flag(priority, high),
    Now = now_ms(),
    self() ! tick,
    {ok, #s{nodes = Nodes, last_tick = Now}}.

configured_nodes() ->
    case application:get_env(evatar, cluster) of
        {ok, Nodes} when is_list(Nodes) ->
            [N || N <- Nodes, is_atom(N)];
        _ ->
            %% Operator configuration, not network input: atoms are fine here.
            case os:getenv("EVATAR_PEERS") of
                false -> [];
                Peers -> [list_to_atom(string:trim(P))
                          || P <- string:split(Peers, ",", all), string:trim(P) =/= ""]
            end
    end.

%% @private
-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call(refresh_now, _From, S) ->
    {reply, ok, tick(S)};
handle_call(_Request, _From, S) ->
    {reply, {error, unknown_call}, S}.

%% @private
-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) ->
    {noreply, S}.

%% @private
-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info(tick, S) ->
    erlang:send_after(opt(heartbeat_ms), self(), tick),
    {noreply, tick(S)};
handle_info({evatar_ha, 1, {hb, Node}}, #s{heard = Heard} = S) ->
    Now = now_ms(),
    true = ets:insert(?TABLE, {{heard, Node}, Now}),
    {noreply, S#s{heard = Heard#{Node => Now}}};
handle_info({evatar_ha, 1, {inventory, _Node, Instances}}, S) ->
    _ = [case evatar_registry:whereis_name(Id) of
             undefined -> ok;
             Local when Local =/= Pid -> evatar_ha_proto_v1:peer_instance(Local, {Pid, Role, Epoch});
             _ -> ok
         end || {Id, Pid, Role, Epoch} <- Instances, is_binary(Id)],
    {noreply, S};
handle_info({evatar_ha, 1, {ask, Id, ReplyTo}}, S) ->
    ok = evatar_ha_proto_v1:instance(ReplyTo, Id, node(), evatar_registry:role(Id)),
    {noreply, S};
handle_info({evatar_ha, 1, {vote, _, _, _, _, _, _}} = Msg, S) ->
    ok = hand_on(evatar_ha_voter, Msg),
    {noreply, S};
handle_info({evatar_ha, 1, {restore_vote, _, _, _, _}} = Msg, S) ->
    ok = hand_on(evatar_ha_voter, Msg),
    {noreply, S};
handle_info({evatar_ha, 1, {register, _, _, _, _}} = Msg, S) ->
    ok = hand_on(evatar_ha_voter, Msg),
    {noreply, S};
handle_info({evatar_ha, 1, {start_standby, _, _, _, _}} = Msg, S) ->
    ok = hand_on(evatar_ha_starter, Msg),
    {noreply, S};
handle_info({nodedown, Node}, #s{alive = Alive, heard = Heard} = S) ->
    true = ets:delete(?TABLE, {heard, Node}),
    S1 = S#s{heard = maps:remove(Node, Heard)},
    case Alive of
        #{Node := _} ->
            ?LOG_WARNING(#{what => node_down, node => Node}),
            true = ets:delete(?TABLE, {alive, Node}),
            broadcast({node_down, Node}),
            {noreply, S1#s{alive = maps:remove(Node, Alive)}};
        #{} ->
            {noreply, S1}
    end;
handle_info({nodeup, _Node}, S) ->
    {noreply, S};
handle_info(_Msg, S) ->
    {noreply, S}.

%% A request for the voter or the starter, as it came. Dropped while that
%% process is restarting, as a lost message is: the instance that asked
%% decides without this node's answer, or places its standby again.
hand_on(Name, Msg) ->
    case whereis(Name) of
        undefined -> ok;
        Pid -> Pid ! Msg, ok
    end.

%% ---------------------------------------------------------------------------
%% The periodic evaluation
%% ---------------------------------------------------------------------------

tick(#s{nodes = Nodes, last_tick = Last} = S) ->
    Now = now_ms(),
    Suspect = opt(suspect_ms),
    Connected = erlang:nodes(),
    Peers = [N || N <- Nodes, N =/= node()],
    S0 = discount(evatar_ha_membership:own_pause(Last, Now, opt(heartbeat_ms)), Now, S),
    Stall = evatar_ha_membership:stall_ms(opt(heartbeat_ms), opt(lease_ms)),
    _ = case evatar_ha_membership:stalled(Last, Now, Stall) of
            true ->
                %% Long enough for the others to have suspected this node,
                %% whatever their clocks within the drift bound: its
                %% actives ask the cluster again (evatar_pairing).
                true = ets:insert(?TABLE, {stall_gen, stall_gen() + 1}),
                ?LOG_WARNING(#{what => node_paused, tick_late_ms => Now - Last - opt(heartbeat_ms)}),
                broadcast(stalled);
            false ->
                ok
        end,
    true = ets:insert(?TABLE, {last_tick, Now}),
    _ = [evatar_ha_proto_v1:heartbeat(N, node()) || N <- Peers, lists:member(N, Connected)],
    S2 = lists:foldl(fun(N, Acc) -> evaluate(N, Connected, Now, Suspect, Acc) end, S0, Peers),
    S3 = reconnect(Peers, Connected, Now, S2),
    S4 = quorum(Now, S3),
    S4#s{last_tick = Now}.

%% This node itself was stopped (SIGSTOP), starved or late: nobody is
%% suspected, and the lease is not lost, for the silence this caused
%% (evatar_ha_membership:discount/3).
discount(0, _Now, S) ->
    S;
discount(Paused, Now, #s{heard = Heard} = S) ->
    Heard1 = maps:map(fun(_N, T) -> evatar_ha_membership:discount(T, Paused, Now) end, Heard),
    true = ets:insert(?TABLE, [{{heard, N}, T} || {N, T} <- maps:to_list(Heard1)]),
    S#s{heard = Heard1}.

evaluate(Node, Connected, Now, Suspect, #s{alive = Alive, heard = Heard} = S) ->
    Fresh = lists:member(Node, Connected) andalso
        Now - maps:get(Node, Heard, Now - Suspect - 1) =< Suspect,
    case {is_map_key(Node, Alive), Fresh} of
        {true, false} ->
            ?LOG_WARNING(#{what => node_suspected, node => Node,
                           connected => lists:member(Node, Connected),
                           silent_ms => Now - maps:get(Node, Heard, Now)}),
            true = ets:delete(?TABLE, {alive, Node}),
            broadcast({node_suspected, Node}),
            S#s{alive = maps:remove(Node, Alive)};
        {false, true} ->
            ?LOG_NOTICE(#{what => node_alive, node => Node}),
            true = ets:insert(?TABLE, {{alive, Node}, true}),
            ok = evatar_ha_proto_v1:inventory(Node, evatar_registry:roles()),
            broadcast({node_alive, Node}),
            S#s{alive = Alive#{Node => true}};
        _ ->
            S
    end.

reconnect(Peers, Connected, Now, #s{attempts = Attempts} = S) ->
    case is_alive() of
        false ->
            S;
        true ->
            Due = [N || N <- Peers, not lists:member(N, Connected),
                        Now - maps:get(N, Attempts, Now - ?RECONNECT_MS) >= ?RECONNECT_MS],
            %% connect_node/1 may block for the connection set-up time.
            _ = [spawn(fun() -> net_kernel:connect_node(N) end) || N <- Due],
            S#s{attempts = maps:merge(Attempts, maps:from_list([{N, Now} || N <- Due]))}
    end.

quorum(Now, #s{nodes = Nodes, heard = Heard, quorum = Old} = S) ->
    Lease = opt(lease_ms),
    Connected = erlang:nodes(),
    Recent = [node() | [N || {N, T} <- maps:to_list(Heard), Now - T =< Lease,
                             lists:member(N, Connected)]],
    Q = evatar_ha_membership:majority(Nodes, Recent),
    case Q =:= Old of
        true -> ok;
        false ->
            ?LOG(case Q of true -> notice; false -> warning end,
                 #{what => case Q of true -> majority_heard; false -> majority_lost end,
                   heard => lists:usort(Recent), nodes => Nodes}),
            true = ets:insert(?TABLE, {quorum, Q}),
            broadcast({quorum, Q})
    end,
    S#s{quorum = Q}.

broadcast(Event) ->
    _ = [Pid ! {evatar_cluster, Event} || {_Id, Pid} <- evatar_registry:all()],
    ok.

now_ms() -> erlang:monotonic_time(millisecond).
