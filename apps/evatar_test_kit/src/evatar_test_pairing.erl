%% @doc Test support. Pairings on an evatar_test_cluster: creating one with its
%% active on a chosen node, reading every instance's role and epoch
%% (evatar:ha_status/1 on each node, asked directly by the controller, so
%% a partition between nodes does not hide anything), and waiting for the
%% states the suites assert. Part of the
%% cluster harness (evatar_test_cluster).
-module(evatar_test_pairing).

-export([create/3, create/4, statuses/2, active/2, await_active/4, await_healthy/3,
         healthy/2, roles/2, delete/3, reset/3, start_many/3, placed/2, pmap/3]).

-type status() :: #{role := atom(), epoch := non_neg_integer(), atom() => term()}.

%% @doc Creates pairing Id with its active on node I (evatar_test_traffic's
%% credentials) and waits until its standby is in sync (in a cluster).
-spec create(evatar_test_cluster:cluster(), pos_integer(), binary()) -> ok.
create(C, I, Id) -> create(C, I, Id, #{}).

-spec create(evatar_test_cluster:cluster(), pos_integer(), binary(), map()) -> ok.
create(C, I, Id, Extra) ->
    {ok, _} = evatar_test_cluster:call(C, I, evatar, create_pairing,
                                       [Id, maps:merge(evatar_test_traffic:pairing_opts(), Extra)]),
    Synced = fun() ->
                     case evatar_test_cluster:call(C, I, evatar, ha_status, [Id]) of
                         {ok, #{synced := true}} -> true;
                         _ -> false
                     end
             end,
    case evatar_test_cluster:nodes(C) of
        [_] -> ok;  % a lone node: no standby to wait for
        _ -> ok = evatar_test_cluster:await(Synced, 60000, {synced, Id})
    end.

%% @doc Many pairings at once, as the failover storms use them: creates
%% each of Ids with its active on node 1, starts a traffic pair for each
%% (evatar_test_traffic:start_pair/3 with PairOpts, owned by the caller; their clients patient
%% enough for 2N reconnections at once on a loaded machine: a 600 s
%% reconnect limit and a 5 s handshake), waits for each pair's first
%% round trip, and reads where each is active ({NodeIndex, Epoch}: node 1
%% unless the machine's load cost node 1 its lease meanwhile). Returns the
%% pairs in the order of Ids, and that placement.
-spec start_many(evatar_test_cluster:cluster(), [binary()], map()) ->
          {[evatar_test_traffic:pair()], #{binary() => {pos_integer(), non_neg_integer()}}}.
start_many(C, Ids, PairOpts) ->
    _ = pmap(fun(Id) -> ok = create(C, 1, Id) end, Ids, 16),
    Eps = evatar_test_cluster:endpoints(C),
    %% Owned by the caller: a pmap worker exits as soon as its pair is up.
    Opts = maps:merge(#{owner => self(),
                        client => #{reconnect_limit => 600000, handshake_timeout => 5000}},
                      PairOpts),
    Pairs = pmap(fun(Id) ->
                         {ok, P} = evatar_test_traffic:start_pair(Eps, Id, Opts),
                         P
                 end, Ids, 16),
    _ = pmap(fun(P) -> {ok, _} = evatar_test_traffic:round_trip(P, 60000) end, Pairs, 32),
    {Pairs, maps:from_list(pmap(fun(Id) -> {Id, placed(C, Id)} end, Ids, 16))}.

%% @doc Where pairing Id is active now: {NodeIndex, Epoch} (waits up to
%% 60 s for an active).
-spec placed(evatar_test_cluster:cluster(), binary()) -> {pos_integer(), non_neg_integer()}.
placed(C, Id) ->
    {ok, I, #{epoch := E}} = await_active(C, Id, fun(_, _) -> true end, 60000),
    {I, E}.

%% @doc F over Items, at most Width at a time (each in a linked process),
%% results in the order of Items.
-spec pmap(fun((A) -> B), [A], pos_integer()) -> [B].
pmap(F, Items, Width) -> pmap(F, Items, Width, []).

pmap(_F, [], _Width, Acc) ->
    lists:append(lists:reverse(Acc));
pmap(F, Items, Width, Acc) ->
    {Batch, Rest} = lists:split(min(Width, length(Items)), Items),
    Parent = self(),
    Refs = [begin
                Ref = make_ref(),
                _ = spawn_link(fun() -> Parent ! {Ref, F(X)} end),
                Ref
            end || X <- Batch],
    Results = [receive {Ref, R} -> R end || Ref <- Refs],
    pmap(F, Rest, Width, [Results | Acc]).

%% @doc Deletes pairing Id through node I (its active).
-spec delete(evatar_test_cluster:cluster(), pos_integer(), binary()) -> term().
delete(C, I, Id) ->
    evatar_test_cluster:call(C, I, evatar, delete_pairing, [Id]).

%% @doc Puts the cluster back as it was for the next test case: every node
%% up (stalled ones resumed, killed ones restarted), no link cut, formed
%% within Timeout ms, and pairing Id deleted.
-spec reset(evatar_test_cluster:cluster(), binary(), pos_integer()) -> ok.
reset(C, Id, Timeout) ->
    ok = evatar_test_cluster:heal(C, reset),
    _ = [ok = evatar_test_cluster:resume(C, I) || #{i := I, status := stalled} <- evatar_test_cluster:info(C)],
    _ = [ok = evatar_test_cluster:restart(C, I) || #{i := I, status := down} <- evatar_test_cluster:info(C)],
    ok = evatar_test_cluster:await_formed(C, Timeout),
    _ = [delete(C, I, Id) || {active, _, I} <- roles(C, Id)],
    ok.

%% @doc The status of every instance of Id on the nodes that are up (a node
%% that does not answer is left out), as {NodeIndex, Status}.
-spec statuses(evatar_test_cluster:cluster(), binary()) -> [{pos_integer(), status()}].
statuses(C, Id) ->
    Up = [I || #{i := I, status := up} <- evatar_test_cluster:info(C)],
    Calls = [{I, evatar_test_cluster:call(C, I, evatar, ha_status, [Id])} || I <- Up],
    [{I, St} || {I, {ok, St}} <- Calls].

%% @doc Roles as a sorted list of {Role, Epoch, NodeIndex}.
-spec roles(evatar_test_cluster:cluster(), binary()) -> [{atom(), non_neg_integer(), pos_integer()}].
roles(C, Id) ->
    lists:sort([{R, E, I} || {I, #{role := R, epoch := E}} <- statuses(C, Id)]).

%% @doc The one active instance: {ok, NodeIndex, Status}, or {error, Roles}
%% when there is none or more than one.
-spec active(evatar_test_cluster:cluster(), binary()) ->
          {ok, pos_integer(), status()} | {error, term()}.
active(C, Id) ->
    All = statuses(C, Id),
    case [{I, St} || {I, #{role := active} = St} <- All] of
        [{I, St}] -> {ok, I, St};
        Other -> {error, {actives, [{I, E} || {I, #{epoch := E}} <- Other]}}
    end.

%% @doc Waits for an active instance accepted by Pred(NodeIndex, Status).
-spec await_active(evatar_test_cluster:cluster(), binary(),
                   fun((pos_integer(), status()) -> boolean()), pos_integer()) ->
          {ok, pos_integer(), status()} | {error, term()}.
await_active(C, Id, Pred, Timeout) ->
    Self = self(),
    Ref = make_ref(),
    case evatar_test_cluster:await(fun() ->
                                  case active(C, Id) of
                                      {ok, I, St} ->
                                          Pred(I, St) andalso (Self ! {Ref, I, St}) =/= x;
                                      _ ->
                                          false
                                  end
                          end, Timeout, {active, Id}) of
        ok -> receive {Ref, I, St} -> {ok, I, St} end;
        {error, _} = Error -> {error, {Error, roles(C, Id)}}
    end.

%% @doc True when Id has exactly two instances on the nodes that are up:
%% one active, and one standby on another node, in sync with it.
-spec healthy(evatar_test_cluster:cluster(), binary()) -> boolean().
healthy(C, Id) ->
    case statuses(C, Id) of
        [{_, _}, {_, _}] = Two ->
            case lists:sort([{R, I, St} || {I, #{role := R} = St} <- Two]) of
                [{active, AI, #{epoch := E, synced := true, standby_node := SN}},
                 {standby, SI, #{epoch := E}}] ->
                    AI =/= SI andalso SN =:= evatar_test_cluster:node(C, SI);
                _ ->
                    false
            end;
        _ ->
            false
    end.

%% @doc Waits until healthy/2 holds.
-spec await_healthy(evatar_test_cluster:cluster(), binary(), pos_integer()) -> ok | {error, term()}.
await_healthy(C, Id, Timeout) ->
    case evatar_test_cluster:await(fun() -> healthy(C, Id) end, Timeout, {healthy, Id}) of
        ok -> ok;
        {error, _} = Error -> {error, {Error, roles(C, Id)}}
    end.
