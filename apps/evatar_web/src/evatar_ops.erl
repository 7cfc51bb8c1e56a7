%% @doc The operator's facade: what the HTTP API (evatar_web_api) and the
%% release's commands (bin/evatar status, pairings, ...) show and do, as
%% plain functions returning JSON-ready maps (binary or atom keys and
%% values, numbers, lists; no pids or tuples). docs/api.md gives every
%% shape. Errors are `{error, #{error := Code, field := Field | null,
%% message := Text}}' with a status for the HTTP API (`status').
-module(evatar_ops).

-export([cluster/0, local_instances/0]).

-export_type([error/0]).

-type error() :: #{error := binary(), field := binary() | null, message := binary(),
                   status := 400..599}.

-define(RPC_TIMEOUT, 5000).

%% ---------------------------------------------------------------------------
%% Cluster
%% ---------------------------------------------------------------------------

%% @doc The cluster as this node sees it: every configured node (up or
%% suspected), whether a majority is heard, and per pairing its active's
%% node, its standby's node, its epoch and whether the standby is synced.
-spec cluster() -> map().
cluster() ->
    #{configured := Configured, up := Up, suspected := Suspected, quorum := Quorum} =
        evatar:cluster_status(),
    Nodes = lists:usort(Configured ++ Up ++ Suspected),
    Instances = instances(Up),
    #{node => node(),
      quorum => Quorum,
      nodes => [#{node => N,
                  self => N =:= node(),
                  configured => lists:member(N, Configured),
                  up => lists:member(N, Up),
                  suspected => lists:member(N, Suspected)} || N <- Nodes],
      pairings => [pairing_ha(Id, [I || {_, #{id := Id1}} = I <- Instances, Id1 =:= Id])
                   || Id <- lists:usort([Id || {_, #{id := Id}} <- Instances]
                                        ++ evatar:catalogued())]}.

%% Every instance on the alive nodes, one call per node.
instances(Up) ->
    Nodes = lists:usort([node() | Up]),
    Results = erpc:multicall(Nodes, ?MODULE, local_instances, [], ?RPC_TIMEOUT),
    [{N, I} || {N, {ok, Is}} <- lists:zip(Nodes, Results), I <- Is].

%% @doc This node's instances of pairings with their high-availability
%% state (for cluster/0, called on every alive node).
-spec local_instances() -> [map()].
local_instances() ->
    [instance(Id, evatar:ha_status(Id)) || #{id := Id} <- evatar:pairings()].

instance(Id, {ok, #{role := Role, epoch := Epoch, standby_node := SN, synced := Synced}}) ->
    #{id => Id, role => Role, epoch => Epoch, node => node(), standby_node => null_if_undefined(SN),
      synced => Synced};
instance(Id, {error, Why}) ->
    #{id => Id, role => Why, epoch => null, node => node(), standby_node => null, synced => false}.

pairing_ha(Id, Instances) ->
    Actives = [I || {_, #{role := active} = I} <- Instances],
    Standbys = [N || {N, #{role := standby}} <- Instances],
    Active = case Actives of
                 [] -> #{};
                 _ -> lists:last(lists:sort(fun(#{epoch := A}, #{epoch := B}) -> A =< B end, Actives))
             end,
    #{id => Id,
      active => maps:get(node, Active, null),
      standby => case {maps:get(standby_node, Active, null), Standbys} of
                     {null, [S | _]} -> S;
                     {S, _} -> S
                 end,
      epoch => maps:get(epoch, Active, lists:max([0 | [E || {_, #{epoch := E}} <- Instances,
                                                             is_integer(E)]])),
      synced => maps:get(synced, Active, false),
      instances => [#{node => N, role => R, epoch => E} || {N, #{role := R, epoch := E}} <- Instances]}.

null_if_undefined(undefined) -> null;
null_if_undefined(V) -> V.
