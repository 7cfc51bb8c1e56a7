%% @doc Internal. Opens a listener's socket and supervises its pool of
%% acceptors. The socket belongs to this supervisor, so it lives exactly as
%% long as the pool; the bound address is published for agent_bridge:address/1.
-module(agent_bridge_acceptors_sup).
-behaviour(supervisor).

-export([start_link/3, init/1]).

-spec start_link(term(), pid(), agent_bridge:listener_opts()) ->
          {ok, pid()} | ignore | {error, term()}.
start_link(Name, ListenerSup, Opts) ->
    supervisor:start_link(?MODULE, {Name, ListenerSup, Opts}).

-spec init({term(), pid(), agent_bridge:listener_opts()}) ->
          {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init({Name, ListenerSup, Opts}) ->
    Ip = maps:get(ip, Opts, {127, 0, 0, 1}),
    SockOpts = [binary, {packet, 4}, {active, false}, {ip, Ip},
                {reuseaddr, true}, {nodelay, true}, {exit_on_close, false},
                %% A blocking write (only the refusal of a socket the guard
                %% turned away) gives up and closes after 5 s.
                {send_timeout, 5000}, {send_timeout_close, true},
                {backlog, maps:get(backlog, Opts, 1024)}],
    case gen_tcp:listen(maps:get(port, Opts, 7400), SockOpts) of
        {ok, LSock} ->
            {ok, Address} = inet:sockname(LSock),
            ok = agent_bridge:publish(Name, Address),
            ConnOpts = agent_bridge_tls:conn_opts(Opts),
            Acceptors = [#{id => {acceptor, N},
                           start => {agent_bridge_acceptor, start_link,
                                     [LSock, ListenerSup, ConnOpts]}}
                         || N <- lists:seq(1, maps:get(acceptors, Opts, 4))],
            {ok, {#{strategy => one_for_one, intensity => 10, period => 10}, Acceptors}};
        {error, Why} ->
            %% A listener that cannot listen is a configuration error: fail
            %% the start with a reason the operator can read.
            exit({listen, Ip, maps:get(port, Opts, 7400), Why})
    end.
