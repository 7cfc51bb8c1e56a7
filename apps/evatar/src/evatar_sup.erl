%% @doc Internal. The top supervisor of evatar: the owner of the per-pairing
%% metrics (evatar_metrics), the pairing registry, the node's voter
%% (evatar_ha_voter) and standby starter (evatar_ha_starter), which the
%% membership process hands requests to, the cluster membership process,
%% the supervisor of all pairings, then the
%% catalogue of pairings (which starts pairings, so it comes after their
%% supervisor; its own crash restarts only itself), and the rebalancer
%% (which moves them; likewise).
%% `rest_for_one': should the registry or the membership process ever die,
%% their tables die with them, so every pairing is restarted (with a cluster,
%% their standbys take over); a pairing's own faults stay inside its own tree.
-module(evatar_sup).
-behaviour(supervisor).

-export([start_link/0, init/1]).

%% @doc Starts the top supervisor, registered as `evatar_sup'.
-spec start_link() -> {ok, pid()} | ignore | {error, term()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

%% @private
-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    Flags = #{strategy => rest_for_one, intensity => 3, period => 10},
    Children = [#{id => evatar_metrics,
                  start => {evatar_metrics, start_link, []},
                  restart => permanent,
                  shutdown => 5000,
                  type => worker},
                #{id => evatar_registry,
                  start => {evatar_registry, start_link, []},
                  restart => permanent,
                  shutdown => 5000,
                  type => worker},
                #{id => evatar_ha_voter,
                  start => {evatar_ha_voter, start_link, []},
                  restart => permanent,
                  shutdown => 5000,
                  type => worker},
                #{id => evatar_ha_starter,
                  start => {evatar_ha_starter, start_link, []},
                  restart => permanent,
                  shutdown => 5000,
                  type => worker},
                #{id => evatar_cluster,
                  start => {evatar_cluster, start_link, []},
                  restart => permanent,
                  shutdown => 5000,
                  type => worker},
                #{id => evatar_pairings_sup,
                  start => {evatar_pairings_sup, start_link, []},
                  restart => permanent,
                  shutdown => infinity,
                  type => supervisor},
                #{id => evatar_catalogue,
                  start => {evatar_catalogue, start_link, []},
                  restart => permanent,
                  shutdown => 5000,
                  type => worker},
                #{id => evatar_rebalancer,
                  start => {evatar_rebalancer, start_link, []},
                  restart => permanent,
                  shutdown => 5000,
                  type => worker}],
    {ok, {Flags, Children}}.
