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
%% It is the node's voter too: it answers the pairings' vote and
%% registration requests with `evatar_ha_core:answer/2' and keeps what it
%% promised in `evatar_ha_promises', on disc when the node has a data
%% directory (read back at boot, before any request is answered). A grant
%% is sent only once its record is on the device: requests that wait in the
%% mailbox are answered together, with one fdatasync (a takeover storm
%% asks for hundreds at once). A record that cannot be written (a full
%% disk) grants nothing; the node says `promise_not_persisted' once, and
%% `promises_persisted' when writes succeed again.
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
-export([init/1, handle_continue/2, handle_call/3, handle_cast/2, handle_info/2]).

-include_lib("kernel/include/logger.hrl").

-define(TABLE, evatar_cluster_view).
%% This node's votes: {PairingId, evatar_ha_core:record()}.
-define(VOTES, evatar_cluster_votes).
-define(RECONNECT_MS, 500).
%% Requests answered with one write at most.
-define(BATCH, 512).

-record(s, {nodes :: [node()],
            alive = #{} :: #{node() => true},
            heard = #{} :: #{node() => integer()},
            quorum = true :: boolean(),
            last_tick :: integer(),
            attempts = #{} :: #{node() => integer()},
            %% The promises on disc; undefined while they could not be read.
            promises :: evatar_ha_promises:log() | undefined,
            %% Why the last write (or read) of promises failed, if it did.
            unwritable = false :: false | term()}).

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
    _ = ets:new(?VOTES, [named_table, protected, set]),
    Nodes = lists:usort([node() | configured_nodes()]),
    true = ets:insert(?TABLE, [{configured, Nodes}, {quorum, true}, {stall_gen, 0},
                               {last_tick, erlang:monotonic_time(millisecond)}]),
    _ = case is_alive() of
            true -> net_kernel:monitor_nodes(true);
            false -> ok
        end,
    Now = now_ms(),
    self() ! tick,
    {ok, #s{nodes = Nodes, last_tick = Now}, {continue, load_promises}}.

%% @private
-spec handle_continue(load_promises, #s{}) -> {noreply, #s{}}.
handle_continue(load_promises, S) ->
    {noreply, load_promises(S)}.

load_promises(S) ->
    Dir = evatar_ha_promises:dir(),
    case evatar_ha_promises:open(Dir) of
        {ok, Log, Entries} ->
            true = ets:insert(?VOTES, Entries),
            S#s{promises = Log};
        {error, Reason} ->
            unwritable(Reason, 0, S)
    end.

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
handle_info({evatar_ha, 1, {vote, Id, Ec, Cand, _Claim, _Active, _Dead}} = Msg, S)
  when is_binary(Id), is_integer(Ec), is_pid(Cand) ->
    {noreply, answer([Msg | more_requests(?BATCH - 1)], S)};
handle_info({evatar_ha, 1, {restore_vote, Id, Ec, Cand, NoneOn}} = Msg, S)
  when is_binary(Id), is_integer(Ec), is_pid(Cand), is_list(NoneOn) ->
    {noreply, answer([Msg | more_requests(?BATCH - 1)], S)};
handle_info({evatar_ha, 1, {register, Id, E, Seq, From}} = Msg, S)
  when is_binary(Id), is_integer(E), is_integer(Seq), is_pid(From) ->
    {noreply, answer([Msg | more_requests(?BATCH - 1)], S)};
handle_info({evatar_ha, 1, {start_standby, Id, Config, Active, Epoch}}, S) ->
    ok = start_standby(Id, Config, Active, Epoch),
    {noreply, S};
handle_info({nodedown, Node}, #s{alive = Alive, heard = Heard} = S) ->
    true = ets:delete(?TABLE, {heard, Node}),
    S1 = S#s{heard = maps:remove(Node, Heard)},
    case Alive of
        #{Node := _} ->
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

%% ---------------------------------------------------------------------------
%% The voter
%% ---------------------------------------------------------------------------

%% The requests waiting behind the first, answered with it.
more_requests(0) ->
    [];
more_requests(N) ->
    receive
        {evatar_ha, 1, {vote, Id, Ec, Cand, _, _, _}} = Msg
          when is_binary(Id), is_integer(Ec), is_pid(Cand) ->
            [Msg | more_requests(N - 1)];
        {evatar_ha, 1, {restore_vote, Id, Ec, Cand, NoneOn}} = Msg
          when is_binary(Id), is_integer(Ec), is_pid(Cand), is_list(NoneOn) ->
            [Msg | more_requests(N - 1)];
        {evatar_ha, 1, {register, Id, E, Seq, From}} = Msg
          when is_binary(Id), is_integer(E), is_integer(Seq), is_pid(From) ->
            [Msg | more_requests(N - 1)]
    after 0 ->
            []
    end.

%% Decides every request in order (each against the records the ones
%% before changed), writes the changed records, then replies: a grant of a
%% pairing whose record changed in this batch only once that is durable.
answer(Msgs, S0) ->
    S = case S0#s.promises of
            undefined -> load_promises(S0);
            _ -> S0
        end,
    {Changed, Replies} = lists:foldl(fun decide/2, {#{}, []}, Msgs),
    case write(maps:to_list(Changed), S) of
        {ok, S1} ->
            _ = [reply(R) || {_Durable, R} <- lists:reverse(Replies)],
            S1;
        {error, Reason, S1} ->
            Lost = [R || {true, R} <- Replies],
            _ = [reply(R) || {false, R} <- lists:reverse(Replies)],
            unwritable(Reason, length(Lost), S1)
    end.

decide({evatar_ha, 1, {vote, Id, Ec, Cand, Claim, Active, Dead}}, {Changed, Replies}) ->
    Record = record(Id, Changed),
    Blocked = lists:any(fun serving/1, [P || P <- evatar_ha_core:blockers(Record, Cand, Active,
                                                                          Dead),
                                             is_pid(P)]),
    Effects = evatar_ha_core:answer({vote, Ec, Cand, Claim, Blocked}, Record),
    effects(Effects, Id, {vote_reply, Cand, Id, Ec}, Changed, Replies);
decide({evatar_ha, 1, {restore_vote, Id, Ec, Cand, NoneOn}}, {Changed, Replies}) ->
    Record = record(Id, Changed),
    Blocked = lists:any(fun serving/1,
                        [P || P <- evatar_ha_core:restore_blockers(
                                          Record, Cand, NoneOn, fun node_of/1,
                                          local_instance(Id)),
                              is_pid(P)]),
    Effects = evatar_ha_core:answer({restore_vote, Ec, Cand, Blocked}, Record),
    effects(Effects, Id, {vote_reply, Cand, Id, Ec}, Changed, Replies);
decide({evatar_ha, 1, {register, Id, E, Seq, From}}, {Changed, Replies}) ->
    Effects = evatar_ha_core:answer({register, E, Seq, From}, record(Id, Changed)),
    effects(Effects, Id, {register_reply, From, Id, {E, Seq}}, Changed, Replies).

effects([{persist, R} | Rest], Id, To, Changed, Replies) ->
    effects(Rest, Id, To, Changed#{Id => R}, Replies);
effects([{reply, {refused, _} = Refused}], _Id, To, Changed, Replies) ->
    {Changed, [{false, {To, Refused}} | Replies]};
effects([{reply, Yes}], Id, To, Changed, Replies) ->
    {Changed, [{is_map_key(Id, Changed), {To, Yes}} | Replies]}.

reply({{vote_reply, Cand, Id, Ec}, Result}) ->
    ok = evatar_ha_proto_v1:vote_reply(Cand, Id, Ec, node(), Result);
reply({{register_reply, From, Id, Claim}, Result}) ->
    ok = evatar_ha_proto_v1:register_reply(From, Id, Claim, node(), Result).

write([], S) ->
    {ok, S};
write(_Entries, #s{promises = undefined, unwritable = Reason} = S) ->
    {error, Reason, S};
write(Entries, #s{promises = Log} = S) ->
    case evatar_ha_promises:write(Log, Entries) of
        {ok, Log1} ->
            true = ets:insert(?VOTES, Entries),
            _ = case S#s.unwritable of
                    false -> ok;
                    Was -> ?LOG_NOTICE(#{what => promises_persisted, after_error => Was})
                end,
            {ok, compact(S#s{promises = Log1, unwritable = false})};
        {error, Reason, Log1} ->
            {error, Reason, S#s{promises = Log1}}
    end.

compact(#s{promises = Log} = S) ->
    case evatar_ha_promises:needs_compaction(Log, ets:info(?VOTES, size)) of
        true ->
            case evatar_ha_promises:compact(Log, ets:tab2list(?VOTES)) of
                {ok, Log1} ->
                    S#s{promises = Log1};
                {error, Reason, Log1} ->
                    ?LOG_WARNING(#{what => promises_not_compacted, reason => Reason}),
                    S#s{promises = Log1}
            end;
        false ->
            S
    end.

%% Said once, until writes succeed again.
unwritable(Reason, Lost, #s{unwritable = false} = S) ->
    ?LOG_ERROR(#{what => promise_not_persisted, dir => evatar_ha_promises:dir(),
                 reason => Reason, not_granted => Lost,
                 hint => "this node grants no vote and accepts no registration until it can "
                         "write to EVATAR_DATA_DIR again; the others decide without it"}),
    S#s{unwritable = Reason};
unwritable(_Reason, _Lost, S) ->
    S.

record(Id, Changed) ->
    case Changed of
        #{Id := R} -> R;
        #{} -> record(Id)
    end.

record(Id) ->
    case ets:lookup(?VOTES, Id) of
        [{_, R}] -> R;
        [] -> evatar_ha_core:new_record()
    end.

local_instance(Id) ->
    case evatar_registry:role(Id) of
        #{pid := Pid, role := Role} -> {Pid, Role};
        none ->
            %% Not published yet: starting.
            case evatar_registry:whereis_name(Id) of
                undefined -> undefined;
                Pid -> {Pid, starting}
            end
    end.

node_of(Pid) when is_pid(Pid) -> node(Pid);
node_of(_) -> undefined.

%% Whether an instance may still be serving, as far as this node can tell:
%% a local process that is alive, or a remote one whose node is heard.
serving(Pid) when node(Pid) =:= node() -> is_process_alive(Pid);
serving(Pid) -> alive_now(node(Pid)).

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
            true = ets:delete(?TABLE, {alive, Node}),
            broadcast({node_suspected, Node}),
            S#s{alive = maps:remove(Node, Alive)};
        {false, true} ->
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
        false -> true = ets:insert(?TABLE, {quorum, Q}), broadcast({quorum, Q})
    end,
    S#s{quorum = Q}.

broadcast(Event) ->
    _ = [Pid ! {evatar_cluster, Event} || {_Id, Pid} <- evatar_registry:all()],
    ok.

start_standby(Id, Config, Active, Epoch) when is_binary(Id), is_pid(Active) ->
    case evatar_registry:whereis_name(Id) of
        undefined ->
            case evatar_pairings_sup:start_pairing(Id, Config, {standby_for, Active}) of
                {ok, _} -> ok;
                {error, Reason} ->
                    logger:notice(#{what => standby_not_started, pairing => Id,
                                    reason => Reason}),
                    ok
            end;
        Local ->
            evatar_ha_proto_v1:peer_instance(Local, {Active, active, Epoch})
    end;
start_standby(_Id, _Config, _Active, _Epoch) ->
    ok.

now_ms() -> erlang:monotonic_time(millisecond).
