%% @doc The MQTT client against a real mosquitto started by the test (see
%% evatar_test_mosquitto), and against a scripted broker on a real socket for what
%% mosquitto cannot be made to do on cue (withhold PUBACKs, ignore PINGREQ).
-module(mqtt_client_SUITE).

-include_lib("common_test/include/ct.hrl").

-export([all/0, groups/0, suite/0, init_per_suite/1, end_per_suite/1,
         init_per_testcase/2, end_per_testcase/2]).
-export([connect_v311/1, connect_v5/1, pubsub_v311/1, pubsub_v5/1, publish_async/1,
         retained/1, will_on_abrupt_close/1, no_will_on_stop/1,
         persistent_session_v311/1, persistent_session_v5/1, broker_restart/1,
         broker_killed/1, subscribe_waits_for_connection/1, unsubscribe/1, tls/1,
         tls_untrusted/1, bad_credentials/1, connect_refused/1, bad_input/1,
         max_packet_size/1,
         inflight_window/1, retransmit_on_reconnect/1, retransmit_on_timeout_v311/1,
         keepalive_timeout/1, malformed_from_broker/1]).

suite() -> [{timetrap, {seconds, 30}}].

all() -> [{group, mosquitto}, {group, scripted}].

groups() ->
    [{mosquitto, [], [connect_v311, connect_v5, pubsub_v311, pubsub_v5, publish_async,
                      retained, will_on_abrupt_close, no_will_on_stop,
                      persistent_session_v311, persistent_session_v5, broker_restart,
                      broker_killed, subscribe_waits_for_connection, unsubscribe, tls,
                      tls_untrusted, bad_credentials, connect_refused, bad_input,
                      max_packet_size]},
     {scripted, [], [inflight_window, retransmit_on_reconnect, retransmit_on_timeout_v311,
                     keepalive_timeout, malformed_from_broker]}].

init_per_suite(Config) ->
    case evatar_test_mosquitto:available() of
        true -> Config;
        false -> {skip, mosquitto_not_installed}
    end.

end_per_suite(_Config) ->
    ok.

init_per_testcase(Case, Config) ->
    Opts = case Case of
               broker_restart -> #{persistence => true};
               persistent_session_v311 -> #{persistence => true};
               persistent_session_v5 -> #{persistence => true};
               tls -> #{tls => true};
               tls_untrusted -> #{tls => true};
               bad_credentials -> #{users => [{<<"alice">>, <<"s3cret">>}]};
               _ -> #{}
           end,
    case lists:member(Case, element(3, lists:keyfind(scripted, 1, groups())))
        orelse Case =:= connect_refused orelse Case =:= subscribe_waits_for_connection of
        true ->
            Config;
        false ->
            {ok, B} = evatar_test_mosquitto:start(Opts),
            [{broker, B} | Config]
    end.

end_per_testcase(_Case, Config) ->
    case ?config(broker, Config) of
        undefined -> ok;
        B -> evatar_test_mosquitto:stop(B)
    end,
    %% Brokers replaced during a case are recorded here.
    case get(extra_broker) of
        undefined -> ok;
        B2 -> evatar_test_mosquitto:stop(B2)
    end,
    ok.

%%--------------------------------------------------------------------
%% Helpers
%%--------------------------------------------------------------------

port(Config) -> maps:get(port, ?config(broker, Config)).

client(Config, Extra) ->
    {ok, C} = mqtt_client:start_link(maps:merge(#{host => {127, 0, 0, 1},
                                                  port => port(Config)}, Extra)),
    ok = mqtt_client:await_connected(C, evatar_test_time:guard()),
    C.

recv(C) ->
    recv(C, 5000).

recv(C, Timeout) ->
    receive
        {mqtt_client, C, {publish, M}} -> M
    after Timeout -> ct:fail({no_message, C})
    end.

event(C, Tag) ->
    receive
        {mqtt_client, C, Ev} when element(1, Ev) =:= Tag -> Ev
    after evatar_test_time:guard() -> ct:fail({no_event, Tag})
    end.

%%--------------------------------------------------------------------
%% mosquitto
%%--------------------------------------------------------------------

%% @doc 3.1.1: the owner is told of the connection, without a kept session.
connect_v311(Config) ->
    C = client(Config, #{protocol => v311}),
    {connected, #{session_present := false}} = event(C, connected),
    #{state := connected, protocol := v311} = mqtt_client:info(C),
    ok = mqtt_client:stop(C),
    false = is_process_alive(C).

%% @doc 5.0: the same, over the 5.0 CONNECT/CONNACK.
connect_v5(Config) ->
    C = client(Config, #{protocol => v5, client_id => <<"v5-client">>}),
    {connected, #{session_present := false}} = event(C, connected),
    #{state := connected, protocol := v5, client_id := <<"v5-client">>} = mqtt_client:info(C),
    ok = mqtt_client:stop(C).

%% @doc 3.1.1: QoS 0 and 1 both ways between two clients.
pubsub_v311(Config) ->
    pubsub(Config, v311).

%% @doc 5.0: QoS 0 and 1 both ways between two clients.
pubsub_v5(Config) ->
    pubsub(Config, v5).

pubsub(Config, V) ->
    A = client(Config, #{protocol => V}),
    B = client(Config, #{protocol => V}),
    {ok, [1]} = mqtt_client:subscribe(A, [{<<"to/a">>, 1}]),
    {ok, [0]} = mqtt_client:subscribe(B, [{<<"to/b/#">>, 0}]),
    ok = mqtt_client:publish(B, <<"to/a">>, <<"q1">>, #{qos => 1}),
    ok = mqtt_client:publish(B, <<"to/a">>, [<<"q">>, $0], #{qos => 0}),
    #{topic := <<"to/a">>, payload := <<"q1">>, qos := 1, retain := false, dup := false} = recv(A),
    #{payload := <<"q0">>, qos := 0} = recv(A),
    ok = mqtt_client:publish(A, <<"to/b/x">>, <<"q1">>, #{qos => 1}),
    ok = mqtt_client:publish(A, <<"to/b/y">>, <<>>, #{qos => 0}),
    %% B subscribed at QoS 0: delivery is downgraded.
    #{topic := <<"to/b/x">>, payload := <<"q1">>, qos := 0} = recv(B),
    #{topic := <<"to/b/y">>, payload := <<>>} = recv(B),
    %% A larger payload (several TCP segments) arrives whole.
    Big = crypto:strong_rand_bytes(300000),
    ok = mqtt_client:publish(B, <<"to/a">>, Big, #{qos => 1}),
    #{payload := Big} = recv(A),
    ok = mqtt_client:stop(A),
    ok = mqtt_client:stop(B).

%% @doc publish_async: one `{puback, Ref}' per QoS 1 message, in order, and
%% every message arrives in order.
publish_async(Config) ->
    Sub = client(Config, #{}),
    Pub = client(Config, #{inflight_window => 8}),
    {ok, [1]} = mqtt_client:subscribe(Sub, [{<<"async">>, 1}]),
    N = 500,
    [ok = mqtt_client:publish_async(Pub, <<"async">>, integer_to_binary(I),
                                    #{qos => 1, ref => I}) || I <- lists:seq(1, N)],
    [receive {mqtt_client, Pub, {puback, I}} -> ok after evatar_test_time:guard() -> ct:fail({no_puback, I}) end
     || I <- lists:seq(1, N)],
    Got = [binary_to_integer(maps:get(payload, recv(Sub))) || _ <- lists:seq(1, N)],
    Got = lists:seq(1, N),
    #{inflight := 0, queued := 0} = mqtt_client:info(Pub),
    ok = mqtt_client:stop(Sub),
    ok = mqtt_client:stop(Pub).

%% @doc A retained message reaches later subscribers flagged `retain', and
%% an empty retained payload clears it.
retained(Config) ->
    Pub = client(Config, #{}),
    ok = mqtt_client:publish(Pub, <<"ret/state">>, <<"on">>, #{qos => 1, retain => true}),
    Sub = client(Config, #{protocol => v5}),
    {ok, [1]} = mqtt_client:subscribe(Sub, [{<<"ret/#">>, 1}]),
    #{topic := <<"ret/state">>, payload := <<"on">>, retain := true} = recv(Sub),
    %% Live messages are not flagged retain for existing subscribers.
    ok = mqtt_client:publish(Pub, <<"ret/state">>, <<"off">>, #{qos => 1, retain => true}),
    #{payload := <<"off">>, retain := false} = recv(Sub),
    ok = mqtt_client:publish(Pub, <<"ret/state">>, <<>>, #{qos => 1, retain => true}),
    #{payload := <<>>} = recv(Sub),
    Sub2 = client(Config, #{}),
    {ok, [1, 1]} = mqtt_client:subscribe(Sub2, [{<<"ret/#">>, 1}, {<<"marker">>, 1}]),
    ok = mqtt_client:publish(Pub, <<"marker">>, <<"m">>, #{qos => 1}),
    %% The marker comes first: nothing retained was left.
    #{topic := <<"marker">>} = recv(Sub2),
    [ok = mqtt_client:stop(C) || C <- [Pub, Sub, Sub2]].

%% @doc The will is published when the client's connection dies without a
%% DISCONNECT (the process is killed and its socket closed by the VM).
will_on_abrupt_close(Config) ->
    Obs = client(Config, #{}),
    {ok, [1]} = mqtt_client:subscribe(Obs, [{<<"dev/+/avail">>, 1}]),
    {ok, W} = mqtt_client:start(#{host => {127, 0, 0, 1}, port => port(Config),
                                  protocol => v5,
                                  will => #{topic => <<"dev/w/avail">>, payload => <<"offline">>,
                                            qos => 1, retain => true}}),
    ok = mqtt_client:await_connected(W, evatar_test_time:guard()),
    exit(W, kill),
    #{topic := <<"dev/w/avail">>, payload := <<"offline">>, qos := 1} = recv(Obs),
    ok = mqtt_client:stop(Obs).

%% @doc stop/1 sends DISCONNECT, so the broker discards the will.
no_will_on_stop(Config) ->
    Obs = client(Config, #{}),
    {ok, [1, 1]} = mqtt_client:subscribe(Obs, [{<<"dev/+/avail">>, 1}, {<<"marker">>, 1}]),
    W = client(Config, #{will => #{topic => <<"dev/w/avail">>, payload => <<"offline">>}}),
    ok = mqtt_client:stop(W),
    ok = mqtt_client:publish(Obs, <<"marker">>, <<"m">>, #{qos => 1}),
    #{topic := <<"marker">>} = recv(Obs),
    ok = mqtt_client:stop(Obs).

%% @doc 3.1.1 persistent session: QoS 1 messages published while the
%% client was away arrive after it reconnects with clean_start false.
persistent_session_v311(Config) ->
    persistent_session(Config, v311).

%% @doc 5.0 persistent session (session expiry set because clean_start is
%% false): the same.
persistent_session_v5(Config) ->
    persistent_session(Config, v5).

persistent_session(Config, V) ->
    Id = <<"persist-", (atom_to_binary(V))/binary>>,
    Opts = #{protocol => V, client_id => Id, clean_start => false},
    S1 = client(Config, Opts),
    {connected, #{session_present := false}} = event(S1, connected),
    {ok, [1]} = mqtt_client:subscribe(S1, [{<<"inbox/#">>, 1}]),
    ok = mqtt_client:stop(S1),
    Pub = client(Config, #{}),
    [ok = mqtt_client:publish(Pub, <<"inbox/", (integer_to_binary(I))/binary>>,
                              integer_to_binary(I), #{qos => 1}) || I <- lists:seq(1, 5)],
    S2 = client(Config, Opts),
    {connected, #{session_present := true}} = event(S2, connected),
    Got = [maps:get(payload, recv(S2)) || _ <- lists:seq(1, 5)],
    Got = [integer_to_binary(I) || I <- lists:seq(1, 5)],
    %% The subscription was kept by the broker, not re-sent: it still works.
    ok = mqtt_client:publish(Pub, <<"inbox/6">>, <<"6">>, #{qos => 1}),
    #{payload := <<"6">>} = recv(S2),
    ok = mqtt_client:stop(S2),
    ok = mqtt_client:stop(Pub).

%% @doc A broker restart (SIGTERM, start on the same port) is survived: the
%% client reconnects, resubscribes, picks up retained state and flows again.
broker_restart(Config) ->
    B = ?config(broker, Config),
    Pub = client(Config, #{reconnect => #{min_ms => 50, max_ms => 400}}),
    Sub = client(Config, #{reconnect => #{min_ms => 50, max_ms => 400}, protocol => v5}),
    ok = mqtt_client:publish(Pub, <<"home/lamp">>, <<"on">>, #{qos => 1, retain => true}),
    {ok, [1]} = mqtt_client:subscribe(Sub, [{<<"home/#">>, 1}]),
    #{payload := <<"on">>, retain := true} = recv(Sub),
    {connected, _} = event(Sub, connected),
    {ok, B2} = evatar_test_mosquitto:restart(B),
    put(extra_broker, B2),
    {disconnected, _} = event(Sub, disconnected),
    {connected, #{session_present := false}} = event(Sub, connected),
    %% Resubscribed: the retained state comes again.
    #{topic := <<"home/lamp">>, payload := <<"on">>, retain := true} = recv(Sub),
    ok = mqtt_client:await_connected(Pub, evatar_test_time:guard()),
    ok = mqtt_client:publish(Pub, <<"home/lamp">>, <<"off">>, #{qos => 1}),
    #{payload := <<"off">>, retain := false} = recv(Sub),
    ok = mqtt_client:stop(Pub),
    ok = mqtt_client:stop(Sub).

%% @doc A broker killed with SIGKILL and started again: QoS 1 messages
%% published during the outage are queued and delivered after reconnection.
broker_killed(Config) ->
    B = ?config(broker, Config),
    Opts = #{reconnect => #{min_ms => 50, max_ms => 200}},
    Pub = client(Config, Opts),
    Sub = client(Config, Opts),
    {ok, [1]} = mqtt_client:subscribe(Sub, [{<<"k">>, 1}]),
    {connected, _} = event(Sub, connected),
    ok = evatar_test_mosquitto:kill(B, kill),
    {disconnected, _} = event(Pub, disconnected),
    {disconnected, _} = event(Sub, disconnected),
    %% Published while the broker is down: queued, sent after reconnect.
    Self = self(),
    spawn_link(fun() -> Self ! {sent, mqtt_client:publish(Pub, <<"k">>, <<"late">>,
                                                          #{qos => 1})} end),
    {ok, B2} = evatar_test_mosquitto:start(maps:get(opts, B)),
    put(extra_broker, B2),
    {connected, _} = event(Sub, connected),
    %% Sub may resubscribe after Pub's message is routed; wait until then.
    {ok, [1]} = mqtt_client:subscribe(Sub, [{<<"k">>, 1}]),
    receive {sent, ok} -> ok after evatar_test_time:guard() -> ct:fail(publish_not_completed) end,
    ok = mqtt_client:publish(Pub, <<"k">>, <<"after">>, #{qos => 1}),
    Payloads = collect_until(Sub, <<"after">>),
    true = lists:member(<<"after">>, Payloads),
    ok = mqtt_client:stop(Pub),
    ok = mqtt_client:stop(Sub).

collect_until(C, Last) ->
    case recv(C) of
        #{payload := Last} -> [Last];
        #{payload := P} -> [P | collect_until(C, Last)]
    end.

%% @doc Started while no broker is listening: the client backs off and
%% retries, a subscribe call waits, and both complete once a broker starts.
subscribe_waits_for_connection(_Config) ->
    {ok, L} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}]),
    {ok, Port} = inet:port(L),
    ok = gen_tcp:close(L),
    {ok, C} = mqtt_client:start_link(#{host => {127, 0, 0, 1}, port => Port,
                                       reconnect => #{min_ms => 50, max_ms => 200}}),
    {error, timeout} = mqtt_client:await_connected(C, 300),
    Self = self(),
    spawn_link(fun() -> Self ! {subscribed, mqtt_client:subscribe(C, [{<<"w">>, 1}])} end),
    {ok, B} = evatar_test_mosquitto:start(#{port => Port}),
    put(extra_broker, B),
    ok = mqtt_client:await_connected(C, evatar_test_time:guard()),
    receive {subscribed, R} -> {ok, [1]} = R after evatar_test_time:guard() -> ct:fail(no_subscribe) end,
    ok = mqtt_client:publish(C, <<"w">>, <<"x">>, #{qos => 1}),
    #{payload := <<"x">>} = recv(C),
    ok = mqtt_client:stop(C).

%% @doc After unsubscribe no more messages arrive on that filter (a later
%% message on a kept filter proves the earlier one was not delivered).
unsubscribe(Config) ->
    C = client(Config, #{}),
    {ok, [1, 1]} = mqtt_client:subscribe(C, [{<<"u/1">>, 1}, {<<"u/2">>, 1}]),
    ok = mqtt_client:publish(C, <<"u/1">>, <<"a">>, #{qos => 1}),
    #{topic := <<"u/1">>} = recv(C),
    ok = mqtt_client:unsubscribe(C, [<<"u/1">>]),
    #{subscriptions := [{<<"u/2">>, 1}]} = mqtt_client:info(C),
    ok = mqtt_client:publish(C, <<"u/1">>, <<"b">>, #{qos => 1}),
    ok = mqtt_client:publish(C, <<"u/2">>, <<"c">>, #{qos => 1}),
    #{topic := <<"u/2">>, payload := <<"c">>} = recv(C),
    ok = mqtt_client:stop(C).

%% @doc TLS with the broker's certificate verified against the test CA.
tls(Config) ->
    B = ?config(broker, Config),
    TlsOpts = [{verify, verify_peer}, {cacertfile, maps:get(cacertfile, B)},
               {server_name_indication, "localhost"}],
    {ok, C} = mqtt_client:start_link(#{host => "localhost", port => maps:get(tls_port, B),
                                       tls => TlsOpts, protocol => v5}),
    %% As long as the client's own first attempt may take (connect_timeout,
    %% 10 s): the VM's first TLS connection loads ssl, public_key and
    %% crypto, and at load 17 that took more than the 5 s waited before.
    ok = mqtt_client:await_connected(C, evatar_test_time:guard()),
    {ok, [1]} = mqtt_client:subscribe(C, [{<<"tls/#">>, 1}]),
    ok = mqtt_client:publish(C, <<"tls/x">>, <<"secret">>, #{qos => 1}),
    #{payload := <<"secret">>} = recv(C),
    ok = mqtt_client:stop(C).

%% @doc TLS against a certificate the client does not trust fails, with the
%% reason, and the client stops when it may not reconnect.
tls_untrusted(Config) ->
    B = ?config(broker, Config),
    {ok, C} = mqtt_client:start(#{host => {127, 0, 0, 1}, port => maps:get(tls_port, B),
                                  tls => [{verify, verify_peer}, {cacerts, []}],
                                  reconnect => false}),
    {disconnected, {connect_failed, _}} = event(C, disconnected),
    %% The client has given up: waiting for it fails at once.
    {error, _} = mqtt_client:await_connected(C, 5000),
    false = is_process_alive(C).

%% @doc A password file: good credentials connect, a wrong password is
%% refused with a readable reason in both versions and the client stops.
bad_credentials(Config) ->
    Good = client(Config, #{username => <<"alice">>, password => <<"s3cret">>}),
    ok = mqtt_client:stop(Good),
    Base = #{host => {127, 0, 0, 1}, port => port(Config), username => <<"alice">>,
             password => <<"wrong">>},
    {ok, C1} = mqtt_client:start(Base#{protocol => v311}),
    %% mosquitto answers "not authorized" (5 / 0x87) where others say "bad
    %% user name or password" (4 / 0x86).
    {disconnected, {connack_error, R1}} = event(C1, disconnected),
    true = lists:member(R1, [bad_username_or_password, not_authorized]),
    {ok, C2} = mqtt_client:start(Base#{protocol => v5}),
    {disconnected, {connack_error, R2}} = event(C2, disconnected),
    true = lists:member(R2, [bad_username_or_password, not_authorized]),
    %% Anonymous access is off when a password file is given.
    {ok, C3} = mqtt_client:start(maps:remove(password, maps:remove(username, Base))),
    {disconnected, {connack_error, _}} = event(C3, disconnected),
    [{error, _} = mqtt_client:await_connected(C, 5000) || C <- [C1, C2, C3]],
    [false = is_process_alive(C) || C <- [C1, C2, C3]].

%% @doc Nobody listening and `reconnect => false': the error is reported and
%% the client exits normally (the linked caller survives).
connect_refused(_Config) ->
    {ok, L} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}]),
    {ok, Port} = inet:port(L),
    ok = gen_tcp:close(L),
    {ok, C} = mqtt_client:start_link(#{host => {127, 0, 0, 1}, port => Port,
                                       reconnect => false}),
    {disconnected, {connect_failed, econnrefused}} = event(C, disconnected),
    {error, _} = mqtt_client:await_connected(C, 1000),
    false = is_process_alive(C).

%% @doc Bad options, topics, filters and payloads are refused with a reason
%% and leave the client running.
bad_input(Config) ->
    {error, {bad_option, keepalive}} =
        mqtt_client:start(#{host => localhost, port => 1883, keepalive => -1}),
    {error, {bad_option, will}} =
        mqtt_client:start(#{host => localhost, port => 1883,
                            will => #{topic => <<"a/#">>, payload => <<>>}}),
    {error, {bad_option, host_and_port}} = mqtt_client:start(#{host => localhost}),
    C = client(Config, #{}),
    {error, {bad_topic, wildcard_in_topic_name}} =
        mqtt_client:publish(C, <<"a/+">>, <<>>, #{qos => 1}),
    {error, {bad_topic, bad_utf8}} = mqtt_client:publish(C, <<"a", 0>>, <<>>, #{}),
    {error, bad_publish_options} = mqtt_client:publish(C, <<"a">>, <<>>, #{qos => 2}),
    {error, bad_payload} = mqtt_client:publish(C, <<"a">>, [a], #{}),
    {error, {bad_topic_filter, {<<"a/#/b">>, 0}}} = mqtt_client:subscribe(C, [{<<"a/#/b">>, 0}]),
    {error, no_topics} = mqtt_client:subscribe(C, []),
    ok = mqtt_client:publish_async(C, <<"#">>, <<>>, #{qos => 1, ref => x}),
    #{state := connected, inflight := 0} = mqtt_client:info(C),
    ok = mqtt_client:stop(C).

%% @doc 5.0: the client announces its maximum packet size and the broker
%% withholds larger messages; 3.1.1 cannot announce it, so an oversized
%% packet drops the connection with the reason and the client reconnects.
max_packet_size(Config) ->
    Pub = client(Config, #{}),
    C5 = client(Config, #{protocol => v5, max_packet_size => 1000}),
    C3 = client(Config, #{protocol => v311, max_packet_size => 1000,
                          reconnect => #{min_ms => 20, max_ms => 50}}),
    {ok, [1]} = mqtt_client:subscribe(C5, [{<<"big/#">>, 1}]),
    {ok, [0]} = mqtt_client:subscribe(C3, [{<<"big/#">>, 0}]),
    {connected, _} = event(C3, connected),
    ok = mqtt_client:publish(Pub, <<"big/1">>, binary:copy(<<"x">>, 2000), #{qos => 1}),
    ok = mqtt_client:publish(Pub, <<"big/2">>, <<"small">>, #{qos => 1}),
    #{topic := <<"big/2">>} = recv(C5),
    {disconnected, {protocol_error, {malformed_packet, {packet_too_large, _, 1000}}}} =
        event(C3, disconnected),
    {connected, _} = event(C3, connected),
    [ok = mqtt_client:stop(C) || C <- [Pub, C5, C3]].

%%--------------------------------------------------------------------
%% Scripted broker
%%--------------------------------------------------------------------

%% @doc At most `inflight_window' QoS 1 messages are unacknowledged on the
%% wire; each PUBACK lets exactly one more out, in order.
inflight_window(_Config) ->
    {L, Port} = listen(),
    {ok, C} = mqtt_client:start_link(#{host => {127, 0, 0, 1}, port => Port,
                                       inflight_window => 3}),
    {S, St0} = accept(L, v311),
    [ok = mqtt_client:publish_async(C, <<"w">>, integer_to_binary(I), #{qos => 1, ref => I})
     || I <- lists:seq(1, 10)],
    {First, St1} = take(S, St0, 3),
    [#{type := publish, payload := <<"1">>}, #{payload := <<"2">>}, #{payload := <<"3">>}] = First,
    {timeout, St2} = next(S, St1, 300),
    #{inflight := 3, queued := 7} = mqtt_client:info(C),
    {St3, Ids} = lists:foldl(
                   fun(I, {StA, [Id | Rest]}) ->
                           send(S, #{type => puback, packet_id => Id}),
                           receive {mqtt_client, C, {puback, I}} -> ok
                           after evatar_test_time:guard() -> ct:fail({no_puback, I}) end,
                           case I =< 7 of
                               true ->
                                   {#{payload := P, packet_id := New}, StB} = next(S, StA, 2000),
                                   P = integer_to_binary(I + 3),
                                   {timeout, StC} = next(S, StB, 100),
                                   {StC, Rest ++ [New]};
                               false ->
                                   {StA, Rest}
                           end
                   end, {St2, [maps:get(packet_id, P) || P <- First]}, lists:seq(1, 10)),
    [] = Ids,
    {timeout, _} = next(S, St3, 100),
    #{inflight := 0, queued := 0} = mqtt_client:info(C),
    ok = mqtt_client:stop(C).

%% @doc Unacknowledged messages are sent again with DUP set, same packet
%% ids, after a reconnect; the queue then continues.
retransmit_on_reconnect(_Config) ->
    {L, Port} = listen(),
    {ok, C} = mqtt_client:start_link(#{host => {127, 0, 0, 1}, port => Port, protocol => v5,
                                       inflight_window => 2,
                                       reconnect => #{min_ms => 20, max_ms => 50}}),
    {S1, St0} = accept(L, v5),
    [ok = mqtt_client:publish_async(C, <<"r">>, integer_to_binary(I), #{qos => 1, ref => I})
     || I <- [1, 2, 3]],
    {[#{packet_id := Id1, dup := false}, #{packet_id := Id2, dup := false}], _} = take(S1, St0, 2),
    ok = gen_tcp:close(S1),
    {disconnected, closed} = event(C, disconnected),
    {S2, St1} = accept(L, v5),
    {[#{packet_id := Id1, dup := true, payload := <<"1">>},
      #{packet_id := Id2, dup := true, payload := <<"2">>}], St2} = take(S2, St1, 2),
    send(S2, #{type => puback, packet_id => Id1}),
    {[#{dup := false, payload := <<"3">>}], _} = take(S2, St2, 1),
    receive {mqtt_client, C, {puback, 1}} -> ok after evatar_test_time:guard() -> ct:fail(no_puback) end,
    ok = mqtt_client:stop(C).

%% @doc 3.1.1: a message unacknowledged for `retry_interval' is sent again
%% with DUP on the same connection.
retransmit_on_timeout_v311(_Config) ->
    {L, Port} = listen(),
    {ok, C} = mqtt_client:start_link(#{host => {127, 0, 0, 1}, port => Port,
                                       retry_interval => 200}),
    {S, St0} = accept(L, v311),
    Self = self(),
    spawn_link(fun() -> Self ! {done, mqtt_client:publish(C, <<"t">>, <<"x">>, #{qos => 1})} end),
    {#{packet_id := Id, dup := false}, St1} = next(S, St0, 2000),
    {#{packet_id := Id, dup := true, payload := <<"x">>}, _} = next(S, St1, 2000),
    send(S, #{type => puback, packet_id => Id}),
    receive {done, ok} -> ok after evatar_test_time:guard() -> ct:fail(no_completion) end,
    ok = mqtt_client:stop(C).

%% @doc The client pings when idle and, when the broker stays silent for
%% the keepalive, drops the connection and reconnects.
keepalive_timeout(_Config) ->
    {L, Port} = listen(),
    {ok, C} = mqtt_client:start_link(#{host => {127, 0, 0, 1}, port => Port, keepalive => 1,
                                       reconnect => #{min_ms => 20, max_ms => 50}}),
    {S, St0} = accept(L, v311),
    {connected, _} = event(C, connected),
    {#{type := pingreq}, _} = next(S, St0, 3000),
    {disconnected, keepalive_timeout} = event(C, disconnected),
    {_S2, _} = accept(L, v311),
    {connected, _} = event(C, connected),
    ok = mqtt_client:stop(C).

%% @doc Malformed bytes from the broker drop the connection with a reason
%% (the client stays alive and reconnects).
malformed_from_broker(_Config) ->
    {L, Port} = listen(),
    {ok, C} = mqtt_client:start_link(#{host => {127, 0, 0, 1}, port => Port,
                                       reconnect => #{min_ms => 20, max_ms => 50}}),
    {S, _} = accept(L, v311),
    {connected, _} = event(C, connected),
    ok = gen_tcp:send(S, <<16#36, 3, 0, 1, "t">>), % PUBLISH with QoS 3
    {disconnected, {protocol_error, {malformed_packet, {malformed, publish, _}}}} =
        event(C, disconnected),
    {_S2, _} = accept(L, v311),
    {connected, _} = event(C, connected),
    true = is_process_alive(C),
    ok = mqtt_client:stop(C).

listen() ->
    {ok, L} = gen_tcp:listen(0, [binary, {active, false}, {ip, {127, 0, 0, 1}},
                                 {reuseaddr, true}]),
    {ok, Port} = inet:port(L),
    {L, Port}.

%% Accepts a client, reads its CONNECT and accepts it.
accept(L, V) ->
    {ok, S} = gen_tcp:accept(L, 5000),
    St0 = {mqtt_client_codec:parser(#{version => V}), []},
    {#{type := connect, proto := V}, St1} = next(S, St0, 5000),
    send(S, #{type => connack, session_present => false, reason_code => 0,
              properties => #{}}, V),
    {S, St1}.

send(S, Packet) ->
    send(S, Packet, v311).

send(S, Packet, V) ->
    ok = gen_tcp:send(S, mqtt_client_codec:encode(Packet, V)).

next(_S, {Parser, [P | Rest]}, _Timeout) ->
    {P, {Parser, Rest}};
next(S, {Parser, []} = St, Timeout) ->
    case gen_tcp:recv(S, 0, Timeout) of
        {ok, Bin} ->
            {ok, Ps, Parser1} = mqtt_client_codec:parse(Bin, Parser),
            next(S, {Parser1, Ps}, Timeout);
        {error, timeout} ->
            {timeout, St}
    end.

take(_S, St, 0) ->
    {[], St};
take(S, St, N) ->
    case next(S, St, 2000) of
        {timeout, _} -> ct:fail({expected_packets, N});
        {P, St1} ->
            {Ps, St2} = take(S, St1, N - 1),
            {[P | Ps], St2}
    end.
