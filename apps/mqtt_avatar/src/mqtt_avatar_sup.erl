%% @doc Internal. Supervises the MQTT Avatars started with
%% {@link mqtt_avatar:start/1}. Children are temporary: an Avatar that
%% crashes is not restarted in a loop (its MQTT and EVATAR sessions go with
%% it; start it again once the cause is known).
-module(mqtt_avatar_sup).
-behaviour(supervisor).

-export([start_link/0, start_child/1]).
-export([init/1]).

-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

-spec start_child(mqtt_avatar:opts()) -> {ok, pid()} | {error, term()}.
start_child(Opts) ->
    supervisor:start_child(?MODULE, [Opts]).

-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    Flags = #{strategy => simple_one_for_one, intensity => 10, period => 60},
    Child = #{id => mqtt_avatar, start => {mqtt_avatar_fsm, start_link, []},
              restart => temporary, shutdown => 5000, type => worker,
              modules => [mqtt_avatar_fsm]},
    {ok, {Flags, [Child]}}.
