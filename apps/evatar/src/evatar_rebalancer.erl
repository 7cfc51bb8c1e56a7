%% @doc Internal. Spreads the pairings' actives and standbys over the live
%% nodes again after a node joins (docs/ha-design.md section 2,
%% "Rebalancing"): after faults every active may sit on one node and every
%% standby on another while a returning node idles.
%%
%% One per node; only the coordinator acts: the smallest live node name,
%% while it hears a majority. `rebalance_delay_ms' after a node became
%% alive it gathers where every pairing's active and standby are (each live
%% node's registry), asks `evatar_placement' for a plan, and sends the
%% first move of at most `rebalance_batch' pairings to their actives
%% (evatar_ha_proto_v1:rebalance/2); a second later it gathers and plans
%% again, until the plan is empty. A pairing moves only through its planned
%% handover and its standby placement, which lose and duplicate nothing; an
%% active that cannot move now (no synced standby, a registration under
%% way) ignores the move and the next round plans again. Two coordinators
%% (views that differ for a moment) only cost extra moves.
%%
%% ```
%%  idle --a node became alive--> waiting (rebalance_delay_ms)
%%  waiting --coordinator, majority--> rounds (1 s apart) --empty plan--> idle
%% '''
-module(evatar_rebalancer).
-behaviour(gen_server).

-include_lib("kernel/include/logger.hrl").

-export([start_link/0, opt/1]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-define(TICK_MS, 500).
-define(ROUND_MS, 1000).
-define(GATHER_TIMEOUT, 2000).

-record(s, {alive :: [node()],
            due :: integer() | undefined,
            rounds = 0 :: non_neg_integer(),
            moves = 0 :: non_neg_integer()}).

%% @doc Starts the rebalancer, registered as `evatar_rebalancer'.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    gen_server:start_link({local, ?MODULE}, ?MODULE, [], []).

%% @doc A rebalancing setting from the `evatar' application environment,
%% with its default: `rebalance' (true), `rebalance_delay_ms' (5000: after
%% a node became alive), `rebalance_batch' (2: pairings moved at once).
-spec opt(rebalance | rebalance_delay_ms | rebalance_batch) -> term().
opt(rebalance) -> application:get_env(evatar, rebalance, true);
opt(rebalance_delay_ms) -> application:get_env(evatar, rebalance_delay_ms, 5000);
opt(rebalance_batch) -> application:get_env(evatar, rebalance_batch, 2).

%% @private
-spec init([]) -> {ok, #s{}}.
init([]) ->
    logger:set_process_metadata(#{domain => [evatar, rebalancer]}),
    erlang:send_after(?TICK_MS, self(), tick),
    {ok, #s{alive = [node()]}}.

%% @private
-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call(_Request, _From, S) ->
    {reply, {error, unknown_call}, S}.

%% @private
-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) ->
    {noreply, S}.

%% @private
-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info(tick, S) ->
    erlang:send_after(?TICK_MS, self(), tick),
    {noreply, tick(S)};
handle_info(_Msg, S) ->
    {noreply, S}.

tick(#s{alive = Before} = S) ->
    Alive = lists:sort(evatar_cluster:alive_nodes()),
    Now = erlang:monotonic_time(millisecond),
    S1 = case Alive -- Before of
             [] -> S#s{alive = Alive};
             _Joined -> S#s{alive = Alive, due = Now + opt(rebalance_delay_ms), rounds = 0}
         end,
    case S1#s.due of
        D when is_integer(D), Now >= D -> run_round(S1);
        _ -> S1
    end.

%% One round: gather, plan, send the first moves.
run_round(#s{alive = Alive} = S) ->
    Coordinator = opt(rebalance) =:= true andalso hd(Alive) =:= node()
        andalso length(Alive) > 1 andalso evatar_cluster:majority_now(),
    case Coordinator andalso gather(Alive) of
        false ->
            S#s{due = undefined};
        error ->
            %% A node did not answer: the next round asks again.
            S#s{due = erlang:monotonic_time(millisecond) + ?ROUND_MS};
        {ok, Placement, Actives} ->
            plan(evatar_placement:plan(Alive, Placement), Placement, Actives, S)
    end.

plan([], _Placement, _Actives, #s{moves = M} = S) ->
    _ = [?LOG_NOTICE(#{what => rebalanced, moves => M}) || M > 0],
    S#s{due = undefined, moves = 0, rounds = 0};
plan(Moves, Placement, Actives, #s{rounds = R} = S) ->
    %% Each round at least one move, and a plan has at most three per
    %% pairing: a plan that does not converge (moves refused again and
    %% again) is given up, until the next node joins.
    case R > 3 * map_size(Placement) + 10 of
        true ->
            ?LOG_WARNING(#{what => rebalance_given_up, rounds => R, left => length(Moves)}),
            S#s{due = undefined, moves = 0, rounds = 0};
        false ->
            Batch = first_per_pairing(Moves, opt(rebalance_batch)),
            _ = [ok = evatar_ha_proto_v1:rebalance(maps:get(Id, Actives), Move)
                 || Move <- Batch, Id <- [element(2, Move)]],
            S#s{due = erlang:monotonic_time(millisecond) + ?ROUND_MS, rounds = R + 1,
                moves = S#s.moves + length(Batch)}
    end.

%% The first move of each of the first `N' pairings of the plan: a
%% pairing's next move waits for the round after its first is done.
first_per_pairing(Moves, N) ->
    {Batch, _} = lists:foldl(fun(Move, {Acc, Seen}) ->
                                     Id = element(2, Move),
                                     case length(Acc) < N andalso not maps:is_key(Id, Seen) of
                                         true -> {[Move | Acc], Seen#{Id => true}};
                                         false -> {Acc, Seen#{Id => true}}
                                     end
                             end, {[], #{}}, Moves),
    lists:reverse(Batch).

%% Every live node's instances: pairings with exactly one active and one
%% standby, on two live nodes, make the placement; the others (moving,
%% degraded, fenced) are left out of this round.
gather(Alive) ->
    Results = erpc:multicall(Alive, evatar_registry, roles, [], ?GATHER_TIMEOUT),
    case [R || {ok, R} <- Results] of
        Lists when length(Lists) =:= length(Alive) ->
            Instances = [{Id, Role, Pid} || {Node, Roles} <- lists:zip(Alive, Lists),
                                            {Id, Pid, Role, _Epoch} <- Roles,
                                            node(Pid) =:= Node],
            ById = lists:foldl(fun({Id, Role, Pid}, Acc) ->
                                       maps:update_with(Id, fun(L) -> [{Role, Pid} | L] end,
                                                        [{Role, Pid}], Acc)
                               end, #{}, Instances),
            Healthy = [{Id, A, S} || {Id, L} <- maps:to_list(ById),
                                     [{active, A}] <- [[X || {active, _} = X <- L]],
                                     [{standby, S}] <- [[X || {standby, _} = X <- L]],
                                     length(L) =:= 2, node(A) =/= node(S)],
            {ok, maps:from_list([{Id, {node(A), node(S)}} || {Id, A, S} <- Healthy]),
             maps:from_list([{Id, A} || {Id, A, _} <- Healthy])};
        _ ->
            error
    end.
