%% @doc Test support: the fault backend that cuts links between nodes with
%% TCP proxies (evatar_test_cluster's `net => proxy', its default). Nodes on
%% loopback; every node dials every other through a proxy of its own
%% (evatar_test_proxy, one per direction of a link), found through the epmd
%% module evatar_test_epmd, which maps each peer to its proxy's port
%% (`-ha_link Short Port' per peer); the controller reaches every node
%% directly. A cut stops the proxies of the link from reading either
%% socket: no FIN, no RST, only silence, as in a real partition; a heal
%% either delivers what waited (`flush', the TCP connections survive) or
%% closes them (`reset').
-module(evatar_test_net_proxy).
-behaviour(evatar_test_cluster).

-export([init/2, cut/3, cut_off/3, heal/3, links_down/1, stop/1]).

%% One proxy per ordered pair: A dials B through {A, B}.
-record(net, {proxies :: #{{pos_integer(), pos_integer()} => pid()}}).

-spec init([string()], evatar_test_cluster:opts()) ->
          {ok, #net{}, [evatar_test_cluster:node_spec()]}.
init(Shorts, _Opts) ->
    Specs = evatar_test_cluster:loopback_specs(length(Shorts)),
    Is = lists:seq(1, length(Shorts)),
    DistPort = fun(B) -> maps:get(dist_port, lists:nth(B, Specs)) end,
    Proxies = maps:from_list([{{A, B}, Proxy}
                              || A <- Is, B <- Is, A =/= B,
                                 {ok, Proxy} <- [evatar_test_proxy:start(DistPort(B))]]),
    Linked = [Spec#{args => ["-epmd_module", "evatar_test_epmd"
                             | lists:append([["-ha_link", lists:nth(B, Shorts),
                                              integer_to_list(evatar_test_proxy:port(
                                                                maps:get({A, B}, Proxies)))]
                                             || B <- Is, B =/= A])]}
              || {A, Spec} <- lists:enumerate(Specs)],
    {ok, #net{proxies = Proxies}, Linked}.

-spec cut([{pos_integer(), pos_integer()}], evatar_test_cluster:ctx(), #net{}) ->
          {ok, #net{}}.
cut(Links, _Ctx, #net{proxies = Proxies} = Net) ->
    _ = [ok = evatar_test_proxy:block(maps:get(L, Proxies))
         || {I, J} <- Links, L <- [{I, J}, {J, I}]],
    {ok, Net}.

-spec cut_off(pos_integer(), evatar_test_cluster:ctx(), #net{}) -> {{error, term()}, #net{}}.
cut_off(_I, _Ctx, Net) ->
    %% The clients reach the nodes directly, not through a proxy.
    {{error, {unsupported, proxy}}, Net}.

-spec heal(evatar_test_cluster:heal(), evatar_test_cluster:ctx(), #net{}) -> {ok, #net{}}.
heal(Mode, _Ctx, #net{proxies = Proxies} = Net) ->
    _ = [ok = evatar_test_proxy:unblock(P, Mode)
         || P <- maps:values(Proxies), evatar_test_proxy:blocked(P)],
    {ok, Net}.

-spec links_down(#net{}) -> [{pos_integer(), pos_integer()}].
links_down(#net{proxies = Proxies}) ->
    lists:usort([{min(A, B), max(A, B)} || {{A, B}, P} <- maps:to_list(Proxies),
                                           evatar_test_proxy:blocked(P)]).

-spec stop(#net{}) -> ok.
stop(#net{proxies = Proxies}) ->
    _ = [catch evatar_test_proxy:stop(P) || P <- maps:values(Proxies)],
    ok.
