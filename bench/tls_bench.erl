%% @doc What TLS costs on the bridge: sequential request/feedback round
%% trips between a VA and an Avatar (both agent_bridge_client, in this
%% node, like the node's bridge) over a plain TCP listener, a TLS one, and
%% a TLS one that requires client certificates, on loopback; then full
%% connects (TCP or TLS handshake, Hello, Welcome, Bye). Prints round trips
%% per second and the node's CPU time per round trip (all schedulers, both
%% ends of each connection, since client and server run here).
%%
%%   rebar3 as bench compile
%%   erl -noshell -pa _build/bench/lib/*/ebin -pa _build/bench/extras/bench \
%%       -eval 'tls_bench:main(), halt().'
%%
%% Options: `{round_trips, N}' per round (default 5000), `{rounds, N}'
%% (default 3, the median is printed), `{connects, N}' (default 200).
-module(tls_bench).

-export([main/0, main/1]).

-spec main() -> ok.
main() -> main([]).

-spec main([{atom(), term()}]) -> ok.
main(Opts) ->
    N = proplists:get_value(round_trips, Opts, 5000),
    Rounds = proplists:get_value(rounds, Opts, 3),
    Connects = proplists:get_value(connects, Opts, 200),
    ok = application:set_env(agent_bridge, listeners, []),
    %% One node, no cluster: a tick of evatar_cluster delayed by the load
    %% (TLS handshakes are CPU work) must not make it fence itself as a
    %% stalled node (suspect_ms, 250 ms by default).
    ok = application:set_env(evatar, suspect_ms, 60000),
    ok = logger:set_primary_config(level, proplists:get_value(log_level, Opts, error)),
    {ok, _} = application:ensure_all_started(agent_bridge),
    Dir = certs(),
    F = fun(Name) -> filename:join(Dir, Name) end,
    Server = #{certfile => F("server.pem"), keyfile => F("server.key")},
    Big = #{max_connections => infinity, handshake => #{rate => infinity},
            conn => #{max_read_rate => infinity}},
    {ok, _} = agent_bridge:start_listener(b_tcp, Big#{port => 0}),
    {ok, _} = agent_bridge:start_listener(b_tls, Big#{port => 0, tls => Server}),
    {ok, _} = agent_bridge:start_listener(b_mtls, Big#{port => 0,
                                                       tls => Server#{cacertfile => F("ca.pem")}}),
    Ca = #{cacertfile => F("ca.pem")},
    Cases = [{"TCP", b_tcp, false, false},
             {"TLS", b_tls, Ca, Ca},
             {"TLS + client certificates", b_mtls,
              Ca#{certfile => F("client-va.pem"), keyfile => F("client-va.key")},
              Ca#{certfile => F("client-av.pem"), keyfile => F("client-av.key")}}],
    io:format("~nround trips (request -> Avatar -> feedback), ~b per round, median of ~b rounds~n",
              [N, Rounds]),
    io:format("~-28s ~12s ~16s~n", ["transport", "rt/s", "CPU us per rt"]),
    [begin
         {Rate, Cpu} = round_trips(Name, Listener, VaTls, AvTls, N, Rounds),
         io:format("~-28s ~12b ~16.1f~n", [Name, Rate, Cpu])
     end || {Name, Listener, VaTls, AvTls} <- Cases],
    io:format("~nconnects (handshake, Hello, Welcome, Bye), ~b each~n", [Connects]),
    io:format("~-28s ~12s ~16s~n", ["transport", "connects/s", "CPU us per conn"]),
    [begin
         {Rate, Cpu} = connects(Listener, VaTls, Connects),
         io:format("~-28s ~12b ~16.1f~n", [Name, Rate, Cpu])
     end || {Name, Listener, VaTls, _} <- Cases],
    ok.

certs() ->
    Dir = filename:join(os:getenv("TMPDIR", "/tmp"),
                        "tls_bench_" ++ integer_to_list(erlang:unique_integer([positive]))),
    Src = proplists:get_value(source, evatar:module_info(compile)),
    Root = filename:dirname(filename:dirname(filename:dirname(filename:dirname(Src)))),
    Out = os:cmd("EVATAR_SERVER_HOSTS='localhost 127.0.0.1' bash "
                 ++ filename:join([Root, "scripts", "gen-bridge-certs.sh"]) ++ " " ++ Dir
                 ++ " va av 2>&1; echo rc=$?"),
    case string:find(Out, "rc=0\n") of
        nomatch -> error({gen_bridge_certs, Out});
        _ -> Dir
    end.

opts(Pairing, Role, Entity, Tls) ->
    #{pairing => Pairing, role => Role, entity_id => Entity, tls => Tls,
      credential => case Role of agent -> <<"va">>; avatar -> <<"av">> end}.

round_trips(Name, Listener, VaTls, AvTls, N, Rounds) ->
    Pairing = iolist_to_binary(["bench-", Name]),
    {ok, _} = evatar:create_pairing(Pairing, #{agent_credential => <<"va">>,
                                               avatar_credential => <<"av">>,
                                               feedback_timeout => 60000}),
    {ok, Addr} = agent_bridge:address(Listener),
    Parent = self(),
    Av = spawn_link(fun() ->
                            {ok, C} = agent_bridge_client:connect(
                                        [Addr], opts(Pairing, avatar, <<"av">>, AvTls)),
                            ok = agent_bridge_client:describe(C, ha_like(avatar)),
                            Parent ! {ready, self()},
                            answer(C)
                    end),
    receive {ready, Av} -> ok end,
    {ok, Va} = agent_bridge_client:connect([Addr], opts(Pairing, agent, <<"va">>, VaTls)),
    ok = agent_bridge_client:describe(Va, ha_like(agent)),
    ok = await_bound(Va),
    _ = [rt(Va) || _ <- lists:seq(1, 200)],
    Results = [begin
                   {_, _} = statistics(runtime),
                   T0 = erlang:monotonic_time(microsecond),
                   _ = [rt(Va) || _ <- lists:seq(1, N)],
                   Us = erlang:monotonic_time(microsecond) - T0,
                   {_, CpuMs} = statistics(runtime),
                   {round(N * 1.0e6 / Us), CpuMs * 1000 / N}
               end || _ <- lists:seq(1, Rounds)],
    ok = agent_bridge_client:close(Va),
    unlink(Av),
    exit(Av, kill),
    ok = evatar:delete_pairing(Pairing),
    {median([R || {R, _} <- Results]), median([C || {_, C} <- Results])}.

connects(Listener, Tls, N) ->
    Pairing = <<"bench-connects">>,
    {ok, _} = evatar:create_pairing(Pairing, #{agent_credential => <<"va">>,
                                               avatar_credential => <<"av">>}),
    {ok, Addr} = agent_bridge:address(Listener),
    {_, _} = statistics(runtime),
    T0 = erlang:monotonic_time(microsecond),
    _ = [begin
             {ok, C} = agent_bridge_client:connect([Addr], opts(Pairing, agent, <<"va">>, Tls)),
             ok = agent_bridge_client:close(C),
             %% The entity id is free again once the node has seen the Bye.
             ok = wait_left(Pairing)
         end || _ <- lists:seq(1, N)],
    Us = erlang:monotonic_time(microsecond) - T0,
    {_, CpuMs} = statistics(runtime),
    ok = evatar:delete_pairing(Pairing),
    {round(N * 1.0e6 / Us), CpuMs * 1000 / N}.

wait_left(Pairing) ->
    case evatar:registry(Pairing) of
        {ok, []} -> ok;
        {ok, _} -> timer:sleep(1), wait_left(Pairing)
    end.

rt(Va) ->
    {ok, #{context := feedback}} =
        agent_bridge_client:request(Va, #{sender => <<"LightEmulator01">>, receiver => <<"Light01">>,
                                          body => #{category => <<"ACTUATOR">>,
                                                    type => <<"TurnLightOn">>,
                                                    parameters => [{<<"Light">>, <<"yes">>}]}},
                                    10000).

answer(C) ->
    receive
        {agent_bridge, C, {signal, #{context := request, id := Id, sender := From,
                                     receiver := To, body := Body}}} ->
            ok = agent_bridge_client:send(C, #{context => feedback, sender => To, receiver => From,
                                               in_reply_to => Id, body => Body}),
            answer(C);
        _ ->
            answer(C)
    end.

await_bound(Va) ->
    receive
        {agent_bridge, Va, {binding, #{bound := [_ | _]}}} -> ok;
        {agent_bridge, Va, {binding, _}} -> await_bound(Va)
    after 10000 -> error(not_bound)
    end.

entry(Cat, Type) -> #{category => Cat, type => Type, parameters => []}.

ha_like(agent) ->
    #{entity_id => <<"va">>, api_name => <<"BENCH VA">>, entity_type => agent,
      context => <<"EmulatorDescription">>,
      components => [#{id => <<"LightEmulator01">>,
                       services => [entry(<<"BEHAVIOUR">>, <<"Light">>)],
                       consumes => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>)]}]};
ha_like(avatar) ->
    #{entity_id => <<"av">>, api_name => <<"BENCH AVATAR">>, entity_type => avatar,
      context => <<"ActuatorDescription">>,
      components => [#{id => <<"Light01">>,
                       services => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>)],
                       consumes => []}]}.

median(L) -> lists:nth((length(L) + 1) div 2, lists:sort(L)).
