%% @doc Internal. One listener: the supervisor of its connections, the
%% guard that admits sockets and counts them (agent_bridge_guard), then the
%% acceptor pool that owns the listening socket. rest_for_one, so losing the
%% connection supervisor restarts the guard and the acceptors that start
%% children in it.
-module(agent_bridge_listener_sup).
-behaviour(supervisor).

-export([start_link/2, init/1, conn_sup/1, guard/1]).

-spec start_link(term(), agent_bridge:listener_opts()) -> {ok, pid()} | ignore | {error, term()}.
start_link(Name, Opts) ->
    supervisor:start_link(?MODULE, {Name, Opts}).

-spec init({term(), agent_bridge:listener_opts()}) ->
          {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init({Name, Opts}) ->
    Conns = #{id => conns,
              start => {agent_bridge_conn_sup, start_link, []},
              type => supervisor},
    Guard = #{id => guard,
              start => {agent_bridge_guard, start_link, [Name, Opts]}},
    Acceptors = #{id => acceptors,
                  start => {agent_bridge_acceptors_sup, start_link, [Name, self(), Opts]},
                  type => supervisor},
    {ok, {#{strategy => rest_for_one, intensity => 5, period => 10}, [Conns, Guard, Acceptors]}}.

%% @doc The connection supervisor of a listener. Acceptors ask after their
%% own start, never from an init/1, so the listener supervisor is free.
-spec conn_sup(pid()) -> pid().
conn_sup(ListenerSup) ->
    child(ListenerSup, conns).

%% @doc The guard of a listener, asked like conn_sup/1.
-spec guard(pid()) -> pid().
guard(ListenerSup) ->
    child(ListenerSup, guard).

child(ListenerSup, Id) ->
    {Id, Pid, _, _} = lists:keyfind(Id, 1, supervisor:which_children(ListenerSup)),
    Pid.
