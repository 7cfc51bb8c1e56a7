%% @doc Internal. Supervises every pairing of this node: one
%% `evatar_pairing_sup' tree per pairing, started and stopped at run time.
%% The trees are `temporary': a pairing that gives up (its own restart limit
%% reached) is gone, and that can never count against this supervisor or the
%% other pairings.
-module(evatar_pairings_sup).
-behaviour(supervisor).

-export([start_link/0, start_pairing/2, start_pairing/3, init/1]).

%% @doc Starts the supervisor, registered as `evatar_pairings_sup'.
-spec start_link() -> {ok, pid()} | ignore | {error, term()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

%% @doc Starts the tree of one pairing; returns its supervisor's pid.
-spec start_pairing(evatar:pairing_id(), evatar_pairing_logic:config()) ->
          {ok, pid()} | {error, term()}.
start_pairing(PairingId, Config) ->
    start_pairing(PairingId, Config, create).

%% @doc Starts the tree of one instance (`create', or a standby); returns
%% its supervisor's pid.
-spec start_pairing(evatar:pairing_id(), evatar_pairing_logic:config(), evatar_pairing:mode()) ->
          {ok, pid()} | {error, term()}.
start_pairing(PairingId, Config, Mode) ->
    case supervisor:start_child(?MODULE, [PairingId, Config, Mode]) of
        {ok, Pid} -> {ok, Pid};
        {ok, Pid, _Info} -> {ok, Pid};
        {error, _} = Error -> Error
    end.

%% @private
-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    Flags = #{strategy => simple_one_for_one, intensity => 10, period => 10},
    Child = #{id => evatar_pairing_sup,
              start => {evatar_pairing_sup, start_link, []},
              restart => temporary,
              shutdown => infinity,
              type => supervisor},
    {ok, {Flags, [Child]}}.
