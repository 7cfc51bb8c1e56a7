%% @doc Test support: the fault backend that cuts links between nodes with
%% cookies (evatar_test_cluster's `net => cookie'). Nodes on loopback, direct
%% links. Cutting {I, J}: node I gets a wrong cookie for J and J one for I
%% (`erlang:set_cookie/2'), then their connection is dropped
%% (`erlang:disconnect_node/1'), so every reconnection attempt, automatic or
%% by evatar_cluster, fails its handshake; healing restores the cookies and
%% evatar_cluster reconnects. The cut is a refusal, not silence: a node sees
%% its connection close at once (a proxy or a namespace cut is silent).
%% Needs no privileges and no proxy: the suites of apps/evatar use it.
-module(evatar_test_net_cookie).
-behaviour(evatar_test_cluster).

-export([init/2, cut/3, cut_off/3, heal/3, links_down/1, stop/1]).

-record(net, {blocked :: atom(), cut = [] :: [{pos_integer(), pos_integer()}]}).

-spec init([string()], evatar_test_cluster:opts()) ->
          {ok, #net{}, [evatar_test_cluster:node_spec()]}.
init(Shorts, _Opts) ->
    %% The wrong cookie: random too (with a known cookie, anyone reaching
    %% a node while the tests run could run code on it).
    {ok, #net{blocked = evatar_test_fixtures:secret_atom()},
     evatar_test_cluster:loopback_specs(length(Shorts))}.

-spec cut([{pos_integer(), pos_integer()}], evatar_test_cluster:ctx(), #net{}) ->
          {ok, #net{}}.
cut(Links, #{names := Names, call := Call}, #net{blocked = Blocked, cut = Cut} = Net) ->
    Ends = [E || {I, J} <- Links, E <- [{I, J}, {J, I}]],
    %% Every cookie first, then the connections: a reconnection between
    %% the two steps would find a cookie still right.
    _ = [Call(I, erlang, set_cookie, [maps:get(J, Names), Blocked]) || {I, J} <- Ends],
    _ = [Call(I, erlang, disconnect_node, [maps:get(J, Names)]) || {I, J} <- Ends],
    {ok, Net#net{cut = lists:usort(Links ++ Cut)}}.

-spec cut_off(pos_integer(), evatar_test_cluster:ctx(), #net{}) -> {{error, term()}, #net{}}.
cut_off(_I, _Ctx, Net) ->
    %% Clients reach a node over TCP, which no cookie stops.
    {{error, {unsupported, cookie}}, Net}.

-spec heal(evatar_test_cluster:heal(), evatar_test_cluster:ctx(), #net{}) -> {ok, #net{}}.
heal(_Mode, #{names := Names, cookie := Cookie, call := Call}, #net{cut = Cut} = Net) ->
    _ = [Call(I, erlang, set_cookie, [maps:get(J, Names), Cookie])
         || {A, B} <- Cut, {I, J} <- [{A, B}, {B, A}]],
    {ok, Net#net{cut = []}}.

-spec links_down(#net{}) -> [{pos_integer(), pos_integer()}].
links_down(#net{cut = Cut}) -> Cut.

-spec stop(#net{}) -> ok.
stop(#net{}) -> ok.
