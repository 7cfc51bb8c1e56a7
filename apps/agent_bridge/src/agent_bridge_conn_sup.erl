%% @doc Internal. Supervises the connections of one listener: temporary
%% children, never restarted (a client reconnects by itself).
-module(agent_bridge_conn_sup).
-behaviour(supervisor).

-export([start_link/0, start_conn/2, init/1]).

-spec start_link() -> {ok, pid()} | ignore | {error, term()}.
start_link() ->
    supervisor:start_link(?MODULE, []).

-spec start_conn(pid(), agent_bridge_conn:opts()) -> {ok, pid()} | {error, term()}.
start_conn(Sup, Opts) ->
    case supervisor:start_child(Sup, [{tcp, Opts}]) of
        {ok, Pid} -> {ok, Pid};
        {error, _} = Error -> Error
    end.

-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    Conn = #{id => conn,
             start => {agent_bridge_conn, start_link, []},
             restart => temporary,
             shutdown => 2000},
    {ok, {#{strategy => simple_one_for_one, intensity => 0, period => 1}, [Conn]}}.
