%% EUnit: agent_bridge:check_listener/1, the listener options check shared
%% by start_listener/2 and the node configuration file.
-module(agent_bridge_check_tests).

-include_lib("eunit/include/eunit.hrl").

accepts_every_documented_option_test() ->
    ok = agent_bridge:check_listener(#{}),
    ok = agent_bridge:check_listener(#{ip => {0, 0, 0, 0}, port => 7400, acceptors => 2,
                                       backlog => 16, name => main,
                                       conn => #{heartbeat => 200, hibernate_after => infinity}}),
    ok = agent_bridge:check_listener(#{ip => {0, 0, 0, 0, 0, 0, 0, 1}, port => 0}),
    ok = agent_bridge:check_listener(#{max_connections => 10,
                                       handshake => #{rate => infinity, burst => 5,
                                                      failure_delay => 0, lockout => 1000},
                                       conn => #{idle_timeout => infinity}}),
    ok = agent_bridge:check_listener(#{max_connections => infinity}).

refuses_bad_limits_test() ->
    {error, <<"max_connections must be", _/binary>>} =
        agent_bridge:check_listener(#{max_connections => 0}),
    {error, <<"unknown handshake option rates">>} =
        agent_bridge:check_listener(#{handshake => #{rates => 1}}),
    {error, <<"burst must be", _/binary>>} =
        agent_bridge:check_listener(#{handshake => #{burst => infinity}}),
    {error, <<"max_connections is a listener option", _/binary>>} =
        agent_bridge:check_listener(#{handshake => #{max_connections => 1}}).

refuses_unknown_options_test() ->
    {error, <<"unknown listener option prot">>} = agent_bridge:check_listener(#{prot => 7400}),
    {error, <<"unknown connection option beat">>} = agent_bridge:check_listener(#{conn => #{beat => 1}}).

refuses_wrong_types_test() ->
    {error, <<"ip must be", _/binary>>} = agent_bridge:check_listener(#{ip => "127.0.0.1"}),
    {error, <<"ip must be", _/binary>>} = agent_bridge:check_listener(#{ip => {1, 2, 3, 256}}),
    {error, <<"port must be", _/binary>>} = agent_bridge:check_listener(#{port => 70000}),
    {error, <<"acceptors must be", _/binary>>} = agent_bridge:check_listener(#{acceptors => 0}),
    {error, <<"heartbeat must be", _/binary>>} = agent_bridge:check_listener(#{conn => #{heartbeat => -1}}),
    {error, <<"conn must be", _/binary>>} = agent_bridge:check_listener(#{conn => []}),
    {error, _} = agent_bridge:check_listener([{port, 1}]).

start_listener_refuses_with_the_message_test() ->
    %% Refused before the supervisor is asked: no application needed.
    {error, {bad_listener, <<"unknown listener option prot">>}} =
        agent_bridge:start_listener(t, #{prot => 1}).
