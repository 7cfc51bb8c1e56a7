%% Common Test suite of the node's metrics (docs/metrics.md): real clients
%% over real TCP join, are refused, send signals and wait for a feedback
%% timeout; the counters scraped before and after (GET /metrics of
%% evatar_web, over TCP), read by the reference
%% parser of the Prometheus text format (Debian's python3-prometheus-client),
%% moved by exactly what happened.
-module(metrics_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-compile([export_all, nowarn_export_all]).

-define(VA_CRED, evatar_test_fixtures:va_credential()).
-define(AV_CRED, evatar_test_fixtures:avatar_credential()).
-define(PYTHON, "/usr/bin/python3").

suite() -> [{timetrap, {seconds, 60}}].

all() ->
    [traffic_moves_counters, label_values_are_escaped, pairing_series_are_capped].

init_per_suite(Config) ->
    case os:cmd(?PYTHON " -c 'import prometheus_client' 2>&1; echo rc=$?") of
        "rc=0\n" ->
            ok = evatar_test_node:start([]),
            ok = evatar_web_test:start(#{}),
            Addr = evatar_test_node:listen(metrics_test,
                                                 #{conn => #{handshake_timeout => evatar_test_time:ms(2000),
                                                             linger => 200}}),
            [{addr, Addr} | Config];
        Out ->
            %% Not a skip: without the reference parser nothing checks the format.
            ct:fail({"python3-prometheus-client is not installed (scripts/ensure-deps.sh)", Out})
    end.

end_per_suite(_Config) ->
    ok = evatar_web_test:stop(),
    ok = evatar_test_node:stop([metrics_test], [agent_bridge]).

init_per_testcase(Case, Config) ->
    Pairing = atom_to_binary(Case),
    %% The feedback timeout is fired by the case (evatar:expire_timer/2) once
    %% the answered request is through: none that load could reach.
    {ok, _} = evatar_test_fixtures:create_pairing(Pairing, #{join_timeout => evatar_test_time:ms(5000),
                                                               feedback_timeout => evatar_test_time:guard()}),
    [{pairing, Pairing} | Config].

end_per_testcase(_Case, Config) ->
    ok = application:unset_env(evatar, metrics_max_pairings),
    _ = evatar:delete_pairing(?config(pairing, Config)),
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% Two joins, two refused joins, a round trip, five sensor readings, a
%% refused signal and a feedback timeout move the node's and the pairing's
%% counters by exactly that much; the output parses.
traffic_moves_counters(Config) ->
    P = ?config(pairing, Config),
    Before = scrape(Config),
    %% Joins (two accepted connections).
    {Va, Av} = bound_pair(Config),
    %% A feedback timeout: a request the Avatar leaves unanswered, sent
    %% first; its timer is fired once the requests after it are answered.
    Av ! {leave_unanswered, <<"unanswered-1">>, self()},
    receive {leaving_unanswered, Av, _} -> ok after evatar_test_time:guard() -> ct:fail(responder_silent) end,
    ok = agent_bridge_client:send(Va, (light_request())#{id => <<"unanswered-1">>,
                                                         context => request}),
    %% Refused joins (two more accepted connections, refused handshakes).
    refused_hello(Config, hello(P, agent, <<"va2">>, <<"wrong">>), <<"BadCredential">>),
    refused_hello(Config, hello(<<"no-such-pairing">>, agent, <<"va">>, ?VA_CRED),
                  <<"UnknownPairing">>),
    %% A request and the Avatar's feedback.
    {ok, #{context := feedback, sender := <<"Light01">>}} =
        agent_bridge_client:request(Va, light_request(), evatar_test_time:guard()),
    %% Five sensor readings, all received.
    Av ! {stream, 5},
    5 = length(collect_sensor(Va, 5)),
    %% A signal refused: NotBound.
    {error, #{body := #{type := <<"NotBound">>}}} =
        agent_bridge_client:request(Va, (light_request())#{receiver => <<"Thermo01">>},
                                    evatar_test_time:guard()),
    %% The unanswered request's feedback: EVATAR's Timeout.
    ok = evatar:expire_timer(P, {feedback, <<"LightEmulator01">>, <<"unanswered-1">>}),
    receive
        {agent_bridge, Va, {signal, #{in_reply_to := <<"unanswered-1">>} = Timeout}} ->
            #{context := feedback, body := #{category := <<"EVATAR">>, type := <<"Timeout">>}} =
                Timeout
    after evatar_test_time:guard() -> ct:fail(no_timeout_feedback)
    end,
    %% The refused sockets are closed: two connections held.
    ok = evatar_test_wait:until(
           fun() -> gauge(scrape(Config), evatar_bridge_connections_open, []) =:= 2 end),
    After = scrape(Config),
    Expected = #{{evatar_joins_total, [{kind, agent_join}]} => 1,
                 {evatar_joins_total, [{kind, avatar_join}]} => 1,
                 {evatar_join_refusals_total, [{reason, bad_credential}]} => 1,
                 {evatar_join_refusals_total, [{reason, unknown_pairing}]} => 1,
                 {evatar_bridge_connections_accepted_total, []} => 4,
                 {evatar_bridge_handshakes_refused_total, [{reason, 'BadCredential'}]} => 1,
                 {evatar_bridge_handshakes_refused_total, [{reason, 'UnknownPairing'}]} => 1,
                 {evatar_signals_routed_total, [{kind, request}]} => 2,
                 {evatar_signals_routed_total, [{kind, feedback}]} => 1,
                 {evatar_signals_routed_total, [{kind, sensor_data}]} => 5,
                 {evatar_signals_refused_total, [{code, 'NotBound'}]} => 1,
                 {evatar_feedback_timeouts_total, []} => 1,
                 {evatar_pairing_signals_routed_total, [{kind, request}, {pairing, P}]} => 2,
                 {evatar_pairing_signals_routed_total, [{kind, feedback}, {pairing, P}]} => 1,
                 {evatar_pairing_signals_routed_total, [{kind, sensor_data}, {pairing, P}]} => 5,
                 {evatar_pairing_signals_refused_total, [{pairing, P}]} => 1,
                 {evatar_pairing_feedback_timeouts_total, [{pairing, P}]} => 1,
                 {evatar_pairing_joins_total, [{pairing, P}]} => 2,
                 {evatar_pairing_join_refusals_total, [{pairing, P}]} => 1},
    Moved = moved(Before, After),
    ?assertEqual(Expected, Moved),
    %% The families carry their type.
    #{evatar_signals_routed := counter, evatar_pairing_instances := gauge,
      evatar_bridge_connections_open := gauge} = families(After),
    ?assertEqual(1, gauge(After, evatar_pairing_instances, [{role, active}])),
    ok = agent_bridge_client:close(Va),
    exit(Av, shutdown).

%% A pairing id with a quote, a backslash and a newline is escaped in its
%% label: the reference parser reads the id back unchanged.
label_values_are_escaped(Config) ->
    Id = <<"odd \"pairing\" \\ with\nnewline">>,
    {ok, _} = evatar_test_fixtures:create_pairing(Id, #{}),
    Key = {evatar_pairing_joins_total, [{pairing, Id}]},
    try
        %% The series appear once the new pairing is active on this node,
        %% which may be after create_pairing returns on a loaded node.
        Samples = evatar_test_wait:value(escaped_pairing_series, fun() -> scrape(Config) end,
                                         fun(S) -> maps:is_key(Key, S) end),
        ?assertEqual(0, maps:get(Key, Samples))
    after
        ok = evatar:delete_pairing(Id)
    end.

%% Beyond metrics_max_pairings a pairing has no series of its own, and the
%% gauge of unlabelled pairings counts it.
pairing_series_are_capped(Config) ->
    P = ?config(pairing, Config),
    ok = application:set_env(evatar, metrics_max_pairings, 1),
    Over = <<"over-the-cap">>,
    {ok, _} = evatar_test_fixtures:create_pairing(Over, #{}),
    try
        %% Read once the new pairing is active (the gauge counts active
        %% pairings only), which may be after create_pairing returns.
        Samples = evatar_test_wait:value(over_the_cap_active, fun() -> scrape(Config) end,
                                         fun(S) -> gauge(S, evatar_metrics_pairings_unlabelled, []) > 0 end),
        ?assert(is_map_key({evatar_pairing_joins_total, [{pairing, P}]}, Samples)),
        ?assertNot(is_map_key({evatar_pairing_joins_total, [{pairing, Over}]}, Samples)),
        ?assertEqual(1, gauge(Samples, evatar_metrics_pairings_unlabelled, []))
    after
        ok = evatar:delete_pairing(Over)
    end.

%% ---------------------------------------------------------------------------
%% Scraping and parsing
%% ---------------------------------------------------------------------------

%% The metrics as the reference parser reads them: #{{Name, Labels} =>
%% Value}, labels sorted, names and label values as the parser gives them
%% (atoms for our own names, binaries for pairing ids).
scrape(Config) ->
    Text = fetch(Config),
    {Families, Samples} = parse(Text, Config),
    put(families, Families),
    Samples.

families(_Samples) ->
    get(families).

%% GET /metrics of evatar_web, over TCP.
fetch(_Config) ->
    {200, Headers, Body} = evatar_web_test:raw(get, "/metrics", [], none),
    "text/plain; version=0.0.4; charset=utf-8" = proplists:get_value("content-type", Headers),
    list_to_binary(Body).

parse(Text, Config) ->
    In = filename:join(?config(priv_dir, Config), "scrape.txt"),
    ok = file:write_file(In, Text),
    Script = filename:join(?config(data_dir, Config), "parse_metrics.py"),
    Out = os:cmd(?PYTHON " " ++ Script ++ " < " ++ In ++ " 2>&1; echo rc=$?"),
    Lines = string:split(string:trim(Out, trailing), "\n", all),
    case lists:last(Lines) of
        "rc=0" -> ok;
        _ -> ct:fail({unparsable_metrics, Out})
    end,
    lists:foldl(fun(Line, {F, S}) -> parse_line(Line, F, S) end, {#{}, #{}},
                lists:droplast(Lines)).

parse_line("# family\t" ++ Rest, F, S) ->
    [Name, Type] = string:split(Rest, "\t", all),
    {F#{list_to_atom(Name) => list_to_atom(Type)}, S};
parse_line(Line, F, S) ->
    [Name, LabelText, Value] = string:split(Line, "\t", all),
    Labels = [label(string:split(L, "=")) || L <- string:lexemes(LabelText, ",")],
    {F, S#{{list_to_atom(Name), Labels} => round(list_to_float(Value))}}.

%% Pairing ids as binaries, our own label values as atoms.
label(["pairing", Hex]) -> {pairing, binary:decode_hex(list_to_binary(Hex))};
label([K, Hex]) -> {list_to_atom(K), binary_to_atom(binary:decode_hex(list_to_binary(Hex)))}.

%% Samples whose value differs, with the difference; a sample missing
%% before counts from 0.
moved(Before, After) ->
    maps:filter(fun(_, V) -> V =/= 0 end,
                maps:map(fun(K, V) -> V - maps:get(K, Before, 0) end,
                         maps:filter(fun({Name, _}, _) -> is_counter(Name) end, After))).

is_counter(Name) ->
    lists:suffix("_total", atom_to_list(Name)).

gauge(Samples, Name, Labels) ->
    maps:get({Name, Labels}, Samples).

%% ---------------------------------------------------------------------------
%% Clients
%% ---------------------------------------------------------------------------

client(Config, Role, Entity) ->
    evatar_test_fixtures:client(?config(addr, Config), ?config(pairing, Config), Role, Entity).

hello(Pairing, Role, Entity, Cred) ->
    evatar_test_fixtures:hello(Pairing, Role, Entity, Cred, 1).

refused_hello(Config, Hello, Code) ->
    Code = evatar_test_fixtures:refused_code(?config(addr, Config), Hello),
    ok.

bound_pair(Config) ->
    Av = start_responder(Config, <<"av">>),
    {ok, Va} = client(Config, agent, <<"va">>),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    _ = evatar_test_fixtures:wait_binding(Va, fun(#{bound := B}) -> B =/= [] end,
                                             evatar_test_time:guard()),
    {Va, Av}.

collect_sensor(Va, N) ->
    [receive
         {agent_bridge, Va, {signal, #{context := sensor_data} = S}} -> S
     after evatar_test_time:guard() -> ct:fail(sensor_data_missing)
     end || _ <- lists:seq(1, N)].

start_responder(Config, Entity) ->
    evatar_test_fixtures:start_responder(fun() -> client(Config, avatar, Entity) end,
                                         evatar_test_fixtures:avatar_description(Entity),
                                         fun sensor/1).

light_request() ->
    #{sender => <<"LightEmulator01">>, receiver => <<"Light01">>,
      body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                parameters => [{<<"Light">>, <<"yes">>}]}}.

sensor(I) ->
    #{context => sensor_data, sender => <<"Thermo01">>, receiver => <<"ThermoEmulator01">>,
      body => #{category => <<"SENSOR">>, type => <<"Temperature">>,
                parameters => [{<<"Value">>, <<"21.5">>}, {<<"N">>, integer_to_binary(I)}]}}.

va_description(Id) ->
    evatar_test_fixtures:va_description(Id).
