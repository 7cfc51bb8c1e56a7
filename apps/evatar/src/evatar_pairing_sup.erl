%% @doc Internal. The tree of one pairing. Its main process, the
%% `evatar_pairing' state machine, is a `significant' child with
%% `auto_shutdown => any_significant', so the tree stops as a unit when the
%% pairing stops normally (`evatar:delete_pairing/1').
%%
%% Restart semantics: the pairing is `transient'. A crash restarts it once
%% more with the same configuration and an empty state: the entities' own
%% processes see the old pairing's `DOWN' and reconnect, which is safer than
%% keeping a state that may have caused the crash. At most `MaxR' restarts in
%% `MaxT' seconds (application env `pairing_restart_limit', default
%% `{2, 60}'); beyond that this supervisor gives up and the pairing is removed
%% (its parent's children are temporary), logged by the supervisor's
%% `reached_max_restart_intensity' report. It stays in the catalogue of
%% pairings, which does not start it again on this node until the node
%% restarts; another node may, once both its instances are gone
%% (docs/ha-design.md, section 11). With a cluster, a restarted
%% instance first asks the other nodes: if its standby took over, it becomes
%% that one's standby (docs/ha-design.md).
-module(evatar_pairing_sup).
-behaviour(supervisor).

-export([start_link/2, start_link/3, init/1]).

%% @doc Starts the tree of a new pairing `PairingId'.
-spec start_link(evatar:pairing_id(), evatar_pairing_logic:config()) ->
          {ok, pid()} | ignore | {error, term()}.
start_link(PairingId, Config) ->
    start_link(PairingId, Config, create).

%% @doc Starts the tree of an instance of pairing `PairingId' (see
%% `evatar_pairing:mode()').
-spec start_link(evatar:pairing_id(), evatar_pairing_logic:config(), evatar_pairing:mode()) ->
          {ok, pid()} | ignore | {error, term()}.
start_link(PairingId, Config, Mode) ->
    supervisor:start_link(?MODULE, {PairingId, Config, Mode}).

%% @private
-spec init({evatar:pairing_id(), evatar_pairing_logic:config(), evatar_pairing:mode()}) ->
          {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init({PairingId, Config, Mode}) ->
    {MaxR, MaxT} = restart_limit(),
    Flags = #{strategy => one_for_all,
              intensity => MaxR,
              period => MaxT,
              auto_shutdown => any_significant},
    Pairing = #{id => evatar_pairing,
                start => {evatar_pairing, start_link, [PairingId, Config, Mode]},
                restart => transient,
                significant => true,
                shutdown => 5000,
                type => worker},
    {ok, {Flags, [Pairing]}}.

restart_limit() ->
    case application:get_env(evatar, pairing_restart_limit, {2, 60}) of
        {MaxR, MaxT} when is_integer(MaxR), MaxR >= 0, is_integer(MaxT), MaxT > 0 ->
            {MaxR, MaxT};
        _ ->
            {2, 60}
    end.
