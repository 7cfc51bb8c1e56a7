%% @doc Internal. One listener: the supervisor of its connections, then the
%% acceptor pool that owns the listening socket. rest_for_one, so losing the
%% connection supervisor restarts the acceptors that start children in it.
-module(agent_bridge_listener_sup).
-behaviour(supervisor).

-export([start_link/2, init/1, conn_sup/1]).

-spec start_link(term(), agent_bridge:listener_opts()) -> {ok, pid()} | ignore | {error, term()}.
start_link(Name, Opts) ->
    supervisor:start_link(?MODULE, {Name, Opts}).

-spec init({term(), agent_bridge:listener_opts()}) ->
          {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init({Name, Opts}) ->
    Conns = #{id => conns,
              start => {agent_bridge_conn_sup, start_link, []},
              type => supervisor},
    Acceptors = #{id => acceptors,
                  start => {agent_bridge_acceptors_sup, start_link, [Name, self(), Opts]},
                  type => supervisor},
    {ok, {#{strategy => rest_for_one, intensity => 5, period => 10}, [Conns, Acceptors]}}.

%% @doc The connection supervisor of a listener. Acceptors ask after their
%% own start, never from an init/1, so the listener supervisor is free.
-spec conn_sup(pid()) -> pid().
conn_sup(ListenerSup) ->
    {conns, Pid, _, _} = lists:keyfind(conns, 1, supervisor:which_children(ListenerSup)),
    Pid.
