%% @doc Test support: the fault backend of a cluster that is never cut
%% (evatar_test_cluster's `net => none', the default for one node): nodes
%% on loopback, direct links; a heal with nothing cut is `ok', a cut is
%% refused.
-module(evatar_test_net_none).
-behaviour(evatar_test_cluster).

-export([init/2, cut/3, cut_off/3, heal/3, links_down/1, stop/1]).

-spec init([string()], evatar_test_cluster:opts()) ->
          {ok, none, [evatar_test_cluster:node_spec()]}.
init(Shorts, _Opts) ->
    {ok, none, evatar_test_cluster:loopback_specs(length(Shorts))}.

-spec cut([{pos_integer(), pos_integer()}], evatar_test_cluster:ctx(), none) ->
          {ok | {error, term()}, none}.
cut([], _Ctx, none) -> {ok, none};
cut(_Links, _Ctx, none) -> {{error, {unsupported, none}}, none}.

-spec cut_off(pos_integer(), evatar_test_cluster:ctx(), none) -> {{error, term()}, none}.
cut_off(_I, _Ctx, none) -> {{error, {unsupported, none}}, none}.

-spec heal(evatar_test_cluster:heal(), evatar_test_cluster:ctx(), none) -> {ok, none}.
heal(_Mode, _Ctx, none) -> {ok, none}.

-spec links_down(none) -> [].
links_down(none) -> [].

-spec stop(none) -> ok.
stop(none) -> ok.
