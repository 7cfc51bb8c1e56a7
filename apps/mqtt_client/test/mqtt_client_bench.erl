%% @doc Quick throughput figures for the MQTT client through a real
%% mosquitto (not a test suite: timings belong in benchmarks). Run with
%% `mqtt_client_bench:run(#{})' from a shell with the test dir compiled.
-module(mqtt_client_bench).

-export([run/1]).

%% @doc Prints and returns round trips per second for one client pair:
%% `rtt' is request (QoS 1) -> device -> response (QoS 1) with one request
%% outstanding; `pipelined' is QoS 1 publish -> receive with the in-flight
%% window full. Options: protocol, payload_size (500), seconds (5), window.
-spec run(map()) -> map().
run(Opts) ->
    {ok, B} = evatar_test_mosquitto:start(#{}),
    try
        V = maps:get(protocol, Opts, v311),
        Secs = maps:get(seconds, Opts, 5),
        Payload = binary:copy(<<"x">>, maps:get(payload_size, Opts, 500)),
        Base = #{host => {127, 0, 0, 1}, port => maps:get(port, B), protocol => V,
                 inflight_window => maps:get(window, Opts, 32)},
        Pid = maps:get(pid, B),
        {Rtt, RttCpu} = cpu(Pid, fun() -> rtt(Base, Payload, Secs) end),
        {Pipe, PipeCpu} = cpu(Pid, fun() -> pipelined(Base, Payload, Secs) end),
        R = #{protocol => V, rtt_per_s => Rtt, pipelined_msgs_per_s => Pipe,
              payload_bytes => byte_size(Payload),
              %% CPU microseconds per round trip / per message: this VM, mosquitto.
              rtt_cpu_us => per(RttCpu, Rtt * Secs),
              pipelined_cpu_us => per(PipeCpu, Pipe * Secs)},
        io:format("~p~n", [R]),
        R
    after
        evatar_test_mosquitto:stop(B)
    end.

cpu(Pid, F) ->
    {_, _} = erlang:statistics(runtime),
    B0 = broker_cpu_ms(Pid),
    R = F(),
    {_, VmMs} = erlang:statistics(runtime),
    {R, {VmMs, broker_cpu_ms(Pid) - B0}}.

per({VmMs, BrokerMs}, N) ->
    #{vm => round(VmMs * 1000 / max(1, N)), mosquitto => round(BrokerMs * 1000 / max(1, N))}.

%% utime + stime from /proc, in ms (USER_HZ is 100 on Linux).
broker_cpu_ms(Pid) ->
    {ok, Stat} = file:read_file("/proc/" ++ integer_to_list(Pid) ++ "/stat"),
    [_, AfterComm] = binary:split(Stat, <<") ">>),
    Fields = binary:split(AfterComm, <<" ">>, [global]),
    (binary_to_integer(lists:nth(12, Fields)) + binary_to_integer(lists:nth(13, Fields))) * 10.

rtt(Base, Payload, Secs) ->
    Self = self(),
    {ok, Dev0} = mqtt_client:start(Base#{owner => Self}),
    ok = mqtt_client:await_connected(Dev0, 5000),
    ok = mqtt_client:stop(Dev0),
    %% The device echoes each request on the response topic.
    Dev = spawn_link(fun() ->
                             {ok, D} = mqtt_client:start_link(Base),
                             ok = mqtt_client:await_connected(D, 5000),
                             {ok, [1]} = mqtt_client:subscribe(D, [{<<"req">>, 1}]),
                             Self ! ready,
                             echo(D)
                     end),
    receive ready -> ok end,
    {ok, A} = mqtt_client:start_link(Base),
    ok = mqtt_client:await_connected(A, 5000),
    {ok, [1]} = mqtt_client:subscribe(A, [{<<"resp">>, 1}]),
    flush(),
    Deadline = erlang:monotonic_time(millisecond) + Secs * 1000,
    T0 = erlang:monotonic_time(microsecond),
    N = rtt_loop(A, Payload, Deadline, 0),
    T1 = erlang:monotonic_time(microsecond),
    ok = mqtt_client:stop(A),
    unlink(Dev),
    exit(Dev, kill),
    round(N * 1000000 / (T1 - T0)).

echo(D) ->
    receive
        {mqtt_client, D, {publish, #{payload := P}}} ->
            ok = mqtt_client:publish_async(D, <<"resp">>, P, #{qos => 1}),
            echo(D);
        _ ->
            echo(D)
    end.

rtt_loop(A, Payload, Deadline, N) ->
    case N band 63 =:= 0 andalso erlang:monotonic_time(millisecond) > Deadline of
        true ->
            N;
        false ->
            ok = mqtt_client:publish_async(A, <<"req">>, Payload, #{qos => 1}),
            receive {mqtt_client, A, {publish, _}} -> ok end,
            rtt_loop(A, Payload, Deadline, N + 1)
    end.

pipelined(Base, Payload, Secs) ->
    {ok, Sub} = mqtt_client:start_link(Base),
    {ok, Pub} = mqtt_client:start(Base#{owner => self()}),
    ok = mqtt_client:await_connected(Sub, 5000),
    ok = mqtt_client:await_connected(Pub, 5000),
    {ok, [1]} = mqtt_client:subscribe(Sub, [{<<"pipe">>, 1}]),
    flush(),
    Deadline = erlang:monotonic_time(millisecond) + Secs * 1000,
    T0 = erlang:monotonic_time(microsecond),
    %% Keep up to 1000 messages ahead of the receiver.
    N = pipe_loop(Pub, Sub, Payload, Deadline, 0, 0),
    T1 = erlang:monotonic_time(microsecond),
    ok = mqtt_client:stop(Pub),
    ok = mqtt_client:stop(Sub),
    round(N * 1000000 / (T1 - T0)).

pipe_loop(Pub, Sub, Payload, Deadline, Sent, Got) when Sent - Got < 1000 ->
    ok = mqtt_client:publish_async(Pub, <<"pipe">>, Payload, #{qos => 1}),
    pipe_loop(Pub, Sub, Payload, Deadline, Sent + 1, Got);
pipe_loop(Pub, Sub, Payload, Deadline, Sent, Got) ->
    receive {mqtt_client, Sub, {publish, _}} -> ok end,
    case Got band 255 =:= 0 andalso erlang:monotonic_time(millisecond) > Deadline of
        true -> drain(Sub, Sent - Got - 1), Got + 1;
        false -> pipe_loop(Pub, Sub, Payload, Deadline, Sent, Got + 1)
    end.

drain(_Sub, 0) -> ok;
drain(Sub, K) -> receive {mqtt_client, Sub, {publish, _}} -> drain(Sub, K - 1) end.

flush() ->
    receive {mqtt_client, _, _} -> flush() after 0 -> ok end.
