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
%% (evatar_ha_proto_v1:rebalance/2); `rebalance_round_ms' later (a
%% second) it gathers and plans again, until the plan is empty. A pairing
%% moves only through its planned handover and its standby placement,
%% which lose and duplicate nothing; an active that cannot move now (no
%% synced standby, a registration under way) ignores the move and the next
%% round plans again. Two coordinators (views that differ for a moment)
%% only cost extra moves.
%%
%% ```
%%  idle --a node became alive--> waiting (rebalance_delay_ms)
%%  waiting --coordinator, majority--> rounds (1 s apart) --empty plan--> idle
%% '''
%%
%% {@link plan_now/0} (tests, through `evatar:run_now(rebalancer)') runs a
%% round now, whatever the delay, and says what it sent: a round early,
%% which plans from the same gathered placement and schedules the next
%% round as a timed one would. A test gives the delay and the round a
%% length no load reaches and fires every round itself, so that what a
%% round decides is checked after it, not raced by the next one.
-module(evatar_rebalancer).
-behaviour(gen_server).

-include_lib("kernel/include/logger.hrl").

-export([start_link/0, opt/1, plan_now/0]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-define(TICK_MS, 500).
-define(GATHER_TIMEOUT, 2000).

%% What a round did: the moves it sent (`[]': the plan is empty, the
%% placement even), or why it sent none: rebalancing is off, this node is
%% alone, another node is the coordinator, no majority is heard, a live
%% node did not answer (the next round asks again), or the plan did not
%% converge (given up until the next node joins).
-type round() :: {ok, [evatar_placement:move()]}
               | {error, off | alone | {not_coordinator, node()} | no_majority | unreachable
                  | given_up}.
-export_type([round/0]).

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
%% a node became alive), `rebalance_round_ms' (1000: between rounds),
%% `rebalance_batch' (2: pairings moved at once).
-spec opt(rebalance | rebalance_delay_ms | rebalance_round_ms | rebalance_batch) -> term().
opt(rebalance) -> application:get_env(evatar, rebalance, true);
opt(rebalance_delay_ms) -> application:get_env(evatar, rebalance_delay_ms, 5000);
opt(rebalance_round_ms) -> application:get_env(evatar, rebalance_round_ms, 1000);
opt(rebalance_batch) -> application:get_env(evatar, rebalance_batch, 2).

%% @doc For tests: one round now on this node, as the timer would run it
%% once due, returning once its moves are sent (each active carries its
%% move out afterwards). Only the coordinator plans; elsewhere the round
%% does nothing, says why, and leaves what was scheduled as it was.
-spec plan_now() -> round().
plan_now() ->
    gen_server:call(?MODULE, plan_now, infinity).

%% @private
-spec init([]) -> {ok, #s{}}.
init([]) ->
    logger:set_process_metadata(#{domain => [evatar, rebalancer]}),
    erlang:send_after(?TICK_MS, self(), tick),
    {ok, #s{alive = [node()]}}.

%% @private
-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call(plan_now, _From, S0) ->
    S = observe(S0, erlang:monotonic_time(millisecond)),
    case coordinator(S#s.alive) of
        ok ->
            {Round, S1} = run_round(S),
            {reply, Round, S1};
        {error, _} = Error ->
            {reply, Error, S}
    end;
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

tick(S0) ->
    Now = erlang:monotonic_time(millisecond),
    S = observe(S0, Now),
    case S#s.due of
        D when is_integer(D), Now >= D -> element(2, run_round(S));
        _ -> S
    end.

%% The live nodes now; a node that joined starts the delay.
observe(#s{alive = Before} = S, Now) ->
    Alive = lists:sort(evatar_cluster:alive_nodes()),
    case Alive -- Before of
        [] -> S#s{alive = Alive};
        _Joined -> S#s{alive = Alive, due = Now + opt(rebalance_delay_ms), rounds = 0}
    end.

%% Only the smallest live node name acts, while it hears a majority.
coordinator(Alive) ->
    case {opt(rebalance) =:= true, Alive} of
        {false, _} -> {error, off};
        {true, [_]} -> {error, alone};
        {true, [First | _]} when First =/= node() -> {error, {not_coordinator, First}};
        {true, _} ->
            case evatar_cluster:majority_now() of
                true -> ok;
                false -> {error, no_majority}
            end
    end.

%% One round: gather, plan, send the first moves.
run_round(#s{alive = Alive} = S) ->
    case coordinator(Alive) of
        {error, _} = Error ->
            {Error, S#s{due = undefined}};
        ok ->
            case gather(Alive) of
                error ->
                    %% A node did not answer: the next round asks again.
                    {{error, unreachable}, next_round(S)};
                {ok, Placement, Actives} ->
                    plan(evatar_placement:plan(Alive, Placement), Placement, Actives, S)
            end
    end.

next_round(S) ->
    S#s{due = erlang:monotonic_time(millisecond) + opt(rebalance_round_ms)}.

plan([], _Placement, _Actives, #s{moves = M} = S) ->
    _ = [?LOG_NOTICE(#{what => rebalanced, moves => M}) || M > 0],
    {{ok, []}, S#s{due = undefined, moves = 0, rounds = 0}};
plan(Moves, Placement, Actives, #s{rounds = R} = S) ->
    %% Each round at least one move, and a plan has at most three per
    %% pairing: a plan that does not converge (moves refused again and
    %% again) is given up, until the next node joins.
    case R > 3 * map_size(Placement) + 10 of
        true ->
            ?LOG_WARNING(#{what => rebalance_given_up, rounds => R, left => length(Moves)}),
            {{error, given_up}, S#s{due = undefined, moves = 0, rounds = 0}};
        false ->
            Batch = first_per_pairing(Moves, opt(rebalance_batch)),
            _ = [ok = evatar_ha_proto_v1:rebalance(maps:get(Id, Actives), Move)
                 || Move <- Batch, Id <- [element(2, Move)]],
            S1 = next_round(S),
            {{ok, Batch}, S1#s{rounds = R + 1, moves = S#s.moves + length(Batch)}}
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
