%% Common Test suite of the bridge over real TCP sockets: handshake, the
%% documented refusals of docs/protocol.md (each while a bystander pairing
%% on the same node keeps doing round trips), routing through the client
%% library, backpressure in both directions and the port connector.
-module(agent_bridge_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-import(evatar_test_wait, [until/1]).

-compile([export_all, nowarn_export_all]).

-define(NS, "xmlns:bil=\"urn:evatar:bil:1\"").
-define(VA_CRED, evatar_test_fixtures:va_credential()).
-define(AV_CRED, evatar_test_fixtures:avatar_credential()).

-define(PACED_RATE, 100).

suite() -> [{timetrap, {seconds, 60}}].

all() ->
    [{group, handshake}, {group, bad_input}, {group, traffic}, {group, decisions},
     {group, backpressure},
     {group, busy}, {group, port}, {group, keeper}].

groups() ->
    [{handshake, [], [handshake_ok, client_connects, endpoints_in_order, bye_leaves]},
     {bad_input, [], [wrong_credential, unknown_pairing, second_va, garbage_bytes,
                      oversize_hello, oversize_frame, empty_frame, bad_first_document,
                      silent_client, malformed_signal_keeps_connection,
                      join_timeout_drops]},
     {traffic, [], [request_feedback, sent_request_feedback_to_owner,
                    sent_request_feedback_to_owner_ha, binding_report, sensor_stream, feedback_timeout,
                    not_bound_error, re_register, pairing_deleted,
                    new_session_waits_for_peer]},
     {decisions, [], [get_binding, resume_sends_binding, request_closed_to_provider,
                      client_get_binding]},
     {backpressure, [], [never_reading_client, flooding_client, keeping_up_never_passive,
                       paced_client_read_at_its_rate]},
     {busy, [], [busy_pairing_refuses_hello, busy_pairing_description,
                  busy_pairing_bye, busy_pairing_operator]},
     {port, [], [port_round_trip]},
     {keeper, [], [listener_port_taken_retries]}].

%% ---------------------------------------------------------------------------
%% Setup
%% ---------------------------------------------------------------------------

init_per_suite(Config) ->
    ok = evatar_test_node:start([]),
    %% The default handshake timeout (5 s) here: the timer starts with the
    %% connection process, and the case's Hello, read by cover-compiled code
    %% on a loaded machine, must not race a short one. silent_client has a
    %% listener of its own with a short timeout (its case waits for it to
    %% fire, and nothing else is on that listener).
    Addr = evatar_test_node:listen(test, #{conn => #{linger => 200}}),
    Silent = evatar_test_node:listen(silent, #{conn => #{handshake_timeout =>
                                                             evatar_test_time:ms(500)}}),
    Small = evatar_test_node:listen(small, #{conn => #{max_out_frames => 50,
                                                             max_out_bytes => 65536,
                                                             pairing_watermark => 20,
                                                             active_n => 4}}),
    Paced = evatar_test_node:listen(paced, #{conn => #{max_read_rate => ?PACED_RATE}}),
    Bystander = start_bystander(Addr),
    [{addr, Addr}, {small, Small}, {paced, Paced}, {silent, Silent}, {bystander, Bystander} | Config].

end_per_suite(Config) ->
    {Va, Av, _} = ?config(bystander, Config),
    ok = agent_bridge_client:close(Va),
    exit(Av, shutdown),
    %% The suites that run next may count the node's pairings.
    ok = evatar:delete_pairing(<<"bystander">>),
    evatar_test_node:stop([test, small, silent, paced], [agent_bridge]).

init_per_testcase(Case, Config) ->
    Pairing = atom_to_binary(Case),
    {ok, _} = evatar_test_fixtures:create_pairing(
                Pairing, #{join_timeout => join_timeout(), feedback_timeout => answer_within(Case)}),
    [{pairing, Pairing} | Config].

%% The cases' join timeout: none waits for it (join_timeout_drops has a
%% pairing of its own), so no load must reach it.
join_timeout() -> evatar_test_time:guard().

%% Short where a case waits for EVATAR's Timeout (and nothing answers);
%% elsewhere the hang guard, so that an answer slowed by a loaded machine
%% (the port program's, a Python process) is never overtaken by a Timeout.
answer_within(Case) when Case =:= feedback_timeout; Case =:= request_closed_to_provider ->
    evatar_test_time:ms(300);
answer_within(_Case) ->
    evatar_test_time:guard().

end_per_testcase(_Case, Config) ->
    %% A busy case may end with its pairing still suspended.
    _ = [sys:resume(Pid) || Pid <- [evatar_registry:whereis_name(?config(pairing, Config))],
                            is_pid(Pid), suspended(Pid)],
    ok = application:unset_env(evatar, call_timeout),
    _ = evatar:delete_pairing(?config(pairing, Config)),
    %% Every refusal case must leave the node and other pairings working.
    ok = bystander_round_trip(Config).

%% ---------------------------------------------------------------------------
%% Handshake
%% ---------------------------------------------------------------------------

%% A Hello with the right credential gets a Welcome naming the session.
handshake_ok(Config) ->
    S = raw_connect(Config),
    ok = gen_tcp:send(S, hello(Config, agent, <<"va">>, ?VA_CRED)),
    {control, {welcome, W}} = recv_doc(S),
    %% JoinTimeout is the pairing's (init_per_testcase), not a listener default.
    #{pairing := P, entity_id := <<"va">>, session_id := Sid, max_frame := 1048576,
      join_timeout := JoinTimeout} = W,
    JoinTimeout = join_timeout(),
    P = ?config(pairing, Config),
    32 = byte_size(Sid),
    ok = gen_tcp:close(S).

%% The client library joins as a VA and reports its session.
client_connects(Config) ->
    {ok, C} = client(Config, agent, <<"va">>),
    {ok, #{entity_id := <<"va">>}} = agent_bridge_client:session(C),
    ok = agent_bridge_client:close(C).

%% Endpoints that refuse connections are skipped in order.
endpoints_in_order(Config) ->
    {ok, Dead} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}]),
    {ok, DeadPort} = inet:port(Dead),
    ok = gen_tcp:close(Dead),
    {Ip, Port} = ?config(addr, Config),
    {ok, C} = agent_bridge_client:connect([{Ip, DeadPort}, {Ip, Port}],
                                          client_opts(Config, agent, <<"va">>)),
    ok = agent_bridge_client:close(C),
    {error, {unreachable, [{{Ip, DeadPort}, econnrefused}]}} =
        agent_bridge_client:connect([{Ip, DeadPort}], client_opts(Config, agent, <<"va">>)).

%% A Bye gets a Bye back and frees the entity id for a new connection.
bye_leaves(Config) ->
    S = raw_connect(Config),
    ok = gen_tcp:send(S, hello(Config, agent, <<"va">>, ?VA_CRED)),
    {control, {welcome, _}} = recv_doc(S),
    ok = gen_tcp:send(S, bil_control:encode({bye, <<>>})),
    {control, {bye, _}} = recv_doc(S),
    {error, closed} = gen_tcp:recv(S, 0, evatar_test_time:guard()),
    {ok, C} = client(Config, agent, <<"va">>),
    ok = agent_bridge_client:close(C).

%% ---------------------------------------------------------------------------
%% Bad input
%% ---------------------------------------------------------------------------

%% A wrong credential is refused with BadCredential, then closed.
wrong_credential(Config) ->
    refused_hello(Config, hello(Config, agent, <<"va">>, <<"guess">>), <<"BadCredential">>),
    {error, {refused, <<"BadCredential">>, _}} =
        agent_bridge_client:connect([?config(addr, Config)],
                                    (client_opts(Config, avatar, <<"av">>))#{credential => <<"x">>}).

%% A pairing that does not exist is refused with UnknownPairing.
unknown_pairing(Config) ->
    Hello = bil_control:encode({hello, #{pairing => <<"no-such-pairing">>, role => agent,
                                         entity_id => <<"va">>, credential => ?VA_CRED,
                                         protocol_version => 1}}),
    refused_hello(Config, Hello, <<"UnknownPairing">>).

%% A second VA for a pairing that has one is refused with Occupied; the first
%% keeps its connection.
second_va(Config) ->
    {ok, C} = client(Config, agent, <<"va">>),
    refused_hello(Config, hello(Config, agent, <<"va2">>, ?VA_CRED), <<"Occupied">>),
    {ok, _} = agent_bridge_client:session(C),
    ok = agent_bridge_client:close(C).

%% Bytes that are not a frame read as a huge length: FrameTooLarge, closed.
garbage_bytes(Config) ->
    {Ip, Port} = ?config(addr, Config),
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {active, false}]),
    ok = gen_tcp:send(S, <<"GET / HTTP/1.1\r\nHost: x\r\n\r\n">>),
    {control, {refused, #{code := <<"FrameTooLarge">>}}} = recv_raw_doc(S),
    {error, closed} = gen_tcp:recv(S, 0, evatar_test_time:guard()).

%% A first frame over the handshake limit (64 KiB) is refused.
oversize_hello(Config) ->
    S = raw_connect(Config),
    ok = gen_tcp:send(S, binary:copy(<<" ">>, 70000)),
    expect_refused(S, <<"FrameTooLarge">>).

%% After the handshake a frame over MaxFrame (1 MiB) is refused and closes.
oversize_frame(Config) ->
    S = joined_raw(Config, agent, <<"va">>, ?VA_CRED),
    ok = gen_tcp:send(S, binary:copy(<<" ">>, 1048577)),
    expect_refused(S, <<"FrameTooLarge">>).

%% A frame of length 0 is refused as Malformed.
empty_frame(Config) ->
    S = joined_raw(Config, agent, <<"va">>, ?VA_CRED),
    ok = gen_tcp:send(S, <<>>),
    expect_refused(S, <<"Malformed">>).

%% A first frame that is not a Hello is refused: BadHandshake or Malformed.
bad_first_document(Config) ->
    S1 = raw_connect(Config),
    ok = gen_tcp:send(S1, bil_control:encode({bye, <<>>})),
    expect_refused(S1, <<"BadHandshake">>),
    S2 = raw_connect(Config),
    ok = gen_tcp:send(S2, <<"<bil:Hello " ?NS "><Pairing>">>),
    expect_refused(S2, <<"Malformed">>),
    S3 = raw_connect(Config),
    ok = gen_tcp:send(S3, bil_control:encode({hello, #{pairing => ?config(pairing, Config),
                                                      role => agent, entity_id => <<"va">>,
                                                      credential => ?VA_CRED,
                                                      protocol_version => 3}})),
    expect_refused(S3, <<"BadHandshake">>).

%% A client that connects and sends nothing gets HandshakeTimeout (500 ms
%% on this listener, on evatar_test_time's scale).
silent_client(Config) ->
    S = raw_connect([{addr, ?config(silent, Config)} | Config]),
    expect_refused(S, <<"HandshakeTimeout">>).

%% A malformed document after the handshake is answered with an error signal
%% and the connection keeps working.
malformed_signal_keeps_connection(Config) ->
    S = joined_raw(Config, agent, <<"va">>, ?VA_CRED),
    ok = gen_tcp:send(S, <<"<bil:Envelope " ?NS "><bil:Header></bil:Envelope>">>),
    {signal, #{context := error, body := #{type := <<"Malformed">>}}} = recv_doc(S),
    ok = gen_tcp:send(S, bil_control:encode({welcome, #{pairing => <<"p">>, entity_id => <<"e">>,
                                                       session_id => <<"s">>, join_timeout => 1,
                                                       max_frame => 1}})),
    {signal, #{context := error, body := #{type := <<"UnexpectedDocument">>}}} = recv_doc(S),
    ok = gen_tcp:send(S, bil:encode_description(va_description(<<"va">>))),
    {control, {binding, _}} = recv_doc(S),
    ok = gen_tcp:close(S).

%% An entity that never describes itself is dropped after the join timeout.
join_timeout_drops(Config) ->
    Pairing = <<"join_timeout_short">>,
    JoinTimeout = evatar_test_time:ms(200),
    {ok, _} = evatar_test_fixtures:create_pairing(Pairing, #{join_timeout => JoinTimeout}),
    S = raw_connect(Config),
    ok = gen_tcp:send(S, bil_control:encode({hello, #{pairing => Pairing, role => avatar,
                                                      entity_id => <<"av">>,
                                                      credential => ?AV_CRED,
                                                      protocol_version => 1}})),
    {control, {welcome, #{join_timeout := JoinTimeout}}} = recv_doc(S),
    {signal, #{context := error, body := #{type := <<"JoinTimeout">>}}} = recv_doc(S),
    expect_refused(S, <<"JoinTimeout">>),
    ok = evatar:delete_pairing(Pairing).

%% ---------------------------------------------------------------------------
%% Traffic
%% ---------------------------------------------------------------------------

%% A request gets its feedback through the pairing; seq and epoch are stamped.
request_feedback(Config) ->
    {Va, _Av} = bound_pair(Config),
    {ok, #{context := feedback, in_reply_to := Id, seq := Seq, epoch := 1}} =
        agent_bridge_client:request(Va, light_request(), evatar_test_time:guard()),
    true = is_binary(Id) andalso is_integer(Seq),
    ok = agent_bridge_client:close(Va).

%% A request given to send/2 (not request/3) has its feedback delivered to
%% the owner as a message.
sent_request_feedback_to_owner(Config) ->
    sent_request_feedback(Config, #{}).

%% The same within an HA session (the window code once kept such feedback).
sent_request_feedback_to_owner_ha(Config) ->
    sent_request_feedback(Config, #{ha => true}).

sent_request_feedback(Config, Extra) ->
    _Av = start_responder(Config, <<"av">>),
    {ok, Va} = agent_bridge_client:connect(
                 [?config(addr, Config)],
                 maps:merge(client_opts(Config, agent, <<"va">>), Extra)),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    _ = wait_binding(Va, fun(#{bound := B}) -> B =/= [] end),
    ok = agent_bridge_client:send(Va, (light_request())#{context => request}),
    receive
        {agent_bridge, Va, {signal, #{context := feedback}}} -> ok
    after evatar_test_time:guard() ->
            ct:fail({no_feedback_to_owner, Extra})
    end,
    ok = agent_bridge_client:close(Va).

%% An HA client whose session the server lost (every node restarted: here
%% the pairing process is killed and restarted empty) gets a new session,
%% describes itself again, and keeps what it sends until a Binding report
%% shows the other side registered again: the request then reaches the
%% Avatar that comes back, instead of being refused as UnknownReceiver.
new_session_waits_for_peer(Config) ->
    Av = start_responder(Config, <<"av">>),
    {ok, Va} = agent_bridge_client:connect([?config(addr, Config)],
                                           (client_opts(Config, agent, <<"va">>))#{ha => true}),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    _ = wait_binding(Va, fun(#{bound := B}) -> B =/= [] end),
    Pairing = evatar_registry:whereis_name(?config(pairing, Config)),
    unlink(Av),
    exit(Pairing, kill),
    receive
        {agent_bridge, Va, {reconnected, #{resumed := Resumed}}} -> false = Resumed
    after evatar_test_time:guard() -> ct:fail(no_reconnect)
    end,
    ok = agent_bridge_client:send(Va, (light_request())#{id => <<"held-1">>,
                                                         context => request}),
    _ = start_responder(Config, <<"av">>),
    receive
        {agent_bridge, Va, {signal, #{in_reply_to := <<"held-1">>} = Answer}} ->
            ?assertMatch(#{context := feedback}, Answer)
    after evatar_test_time:guard() ->
            ct:fail(no_answer)
    end,
    ok = agent_bridge_client:close(Va).

%% Both sides get the Binding report, with what was bound and left unbound.
binding_report(Config) ->
    _Av = start_responder(Config, <<"av">>),
    {ok, Va} = client(Config, agent, <<"va">>),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    #{bound := Bound, unbound := Unbound, entities := Entities} =
        wait_binding(Va, fun(#{bound := B}) -> B =/= [] end),
    [<<"av">>, <<"va">>] = lists:sort(Entities),
    true = lists:any(fun(#{provider := #{component := C}}) -> C =:= <<"Light01">> end, Bound),
    true = lists:any(fun(#{reason := R}) -> R =:= no_provider end, Unbound),
    ok = agent_bridge_client:close(Va).

%% A stream of sensor events from the Avatar arrives in order at the VA.
sensor_stream(Config) ->
    {Va, Av} = bound_pair(Config),
    N = 2000,
    Av ! {stream, N},
    Received = collect_sensor(Va, N, []),
    N = length(Received),
    %% Sent order kept end to end; the mediator's sequence numbers increase.
    Numbers = [binary_to_integer(I) || {_, I} <- Received],
    Numbers = lists:seq(1, N),
    Seqs = [Seq || {Seq, _} <- Received],
    Seqs = lists:usort(Seqs),
    ok = agent_bridge_client:close(Va).

%% An Avatar that does not answer: the VA gets EVATAR's Timeout feedback.
feedback_timeout(Config) ->
    {Va, Av} = bound_pair(Config),
    Av ! mute,
    {ok, #{context := feedback, body := #{category := <<"EVATAR">>, type := <<"Timeout">>}}} =
        agent_bridge_client:request(Va, light_request(), evatar_test_time:guard()),
    ok = agent_bridge_client:close(Va).

%% A receiver outside the sender's bindings gets a NotBound error back.
not_bound_error(Config) ->
    {Va, _Av} = bound_pair(Config),
    {error, #{context := error, body := #{type := <<"NotBound">>}}} =
        agent_bridge_client:request(Va, (light_request())#{receiver => <<"Thermo01">>}, evatar_test_time:guard()),
    {error, #{context := error, body := #{type := <<"UnknownReceiver">>}}} =
        agent_bridge_client:request(Va, (light_request())#{receiver => <<"Nobody">>}, evatar_test_time:guard()),
    ok = agent_bridge_client:close(Va).

%% ---------------------------------------------------------------------------
%% The behaviours docs/protocol.md decided (its appendix "Decisions")
%% ---------------------------------------------------------------------------

%% GetBinding is answered with the current Binding report, to the asker
%% only, and the connection goes on.
get_binding(Config) ->
    S = joined_raw(Config, agent, <<"va">>, ?VA_CRED),
    ok = gen_tcp:send(S, bil:encode_description(va_description(<<"va">>))),
    {control, {binding, #{entities := [<<"va">>], bound := []} = Report}} = recv_doc(S),
    ok = gen_tcp:send(S, bil_control:encode({get_binding, #{}})),
    {control, {binding, Report}} = recv_doc(S),
    %% Before any description too: the report lists the others.
    A = joined_raw(Config, avatar, <<"av">>, ?AV_CRED),
    ok = gen_tcp:send(A, bil_control:encode({get_binding, #{}})),
    {control, {binding, #{entities := [<<"va">>]}}} = recv_doc(A),
    ok = gen_tcp:send(S, bil_control:encode({bye, <<>>})),
    {control, {bye, _}} = recv_doc(S),
    ok = gen_tcp:close(A).

%% A resumed version 2 session is sent the current Binding report right
%% after its Welcome: here it shows the Avatar that described itself while
%% the VA was detached.
resume_sends_binding(Config) ->
    S = raw_connect(Config),
    Hello = #{pairing => ?config(pairing, Config), role => agent, entity_id => <<"va">>,
              credential => ?VA_CRED, protocol_version => 2},
    ok = gen_tcp:send(S, bil_control:encode({hello, Hello})),
    {control, {welcome, #{session_id := Session}}} = recv_doc(S),
    ok = gen_tcp:send(S, bil:encode_description(va_description(<<"va">>))),
    {control, {binding, #{entities := [<<"va">>]}}} = recv_doc_skipping_acks(S),
    ok = gen_tcp:close(S),
    Pairing = ?config(pairing, Config),
    ok = until(fun() ->
                       {ok, Reg} = evatar:registry(Pairing),
                       [false] =:= [A || #{entity := <<"va">>, attached := A} <- Reg]
               end),
    A = joined_raw(Config, avatar, <<"av">>, ?AV_CRED),
    ok = gen_tcp:send(A, bil:encode_description(avatar_description(<<"av">>, false))),
    {control, {binding, #{entities := [<<"va">>, <<"av">>]}}} = recv_doc(A),
    R = raw_connect(Config),
    ok = gen_tcp:send(R, bil_control:encode({resume, Hello#{session_id => Session,
                                                            received => 0, epoch => 1}})),
    {control, {welcome, #{ha := #{resumed := true}}}} = recv_doc(R),
    {control, {binding, #{entities := [<<"va">>, <<"av">>], bound := [_ | _]}}} =
        recv_doc_skipping_acks(R),
    ok = gen_tcp:close(R),
    ok = gen_tcp:close(A).

%% A request that times out: the requester gets Feedback Timeout, the
%% provider an Event RequestClosed, and the provider's late Feedback is
%% answered with the error NoOpenRequest, not delivered.
request_closed_to_provider(Config) ->
    A = joined_raw(Config, avatar, <<"av">>, ?AV_CRED),
    ok = gen_tcp:send(A, bil:encode_description(avatar_description(<<"av">>, false))),
    {control, {binding, _}} = recv_doc(A),
    {ok, Va} = client(Config, agent, <<"va">>),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    {control, {binding, #{bound := [_ | _]}}} = recv_doc(A),
    Self = self(),
    spawn_link(fun() -> Self ! {answer, agent_bridge_client:request(Va, light_request(), evatar_test_time:guard())} end),
    {signal, #{context := request, id := ReqId}} = recv_doc(A),
    {signal, #{context := event, sender := <<"EVATAR">>, origin := evatar,
               receiver := <<"Light01">>, in_reply_to := ReqId,
               body := #{category := <<"EVATAR">>, type := <<"RequestClosed">>,
                         parameters := [{<<"Reason">>, <<"Timeout">>}, {<<"Message">>, _}]}}} =
        recv_doc(A),
    receive
        {answer, {ok, #{body := #{type := <<"Timeout">>}}}} -> ok
    after evatar_test_time:guard() -> ct:fail(no_timeout_feedback)
    end,
    Late = #{id => <<"late-1">>, context => feedback, sender => <<"Light01">>,
             receiver => <<"LightEmulator01">>, in_reply_to => ReqId, timestamp => 1,
             seq => undefined, epoch => undefined,
             body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>, parameters => []}},
    ok = gen_tcp:send(A, bil:encode_signal(Late)),
    {signal, #{context := error, in_reply_to := <<"late-1">>,
               body := #{type := <<"NoOpenRequest">>}}} = recv_doc(A),
    ok = agent_bridge_client:close(Va),
    ok = gen_tcp:close(A).

%% The Erlang client's get_binding/1: the report comes as a message.
client_get_binding(Config) ->
    {Va, _Av} = bound_pair(Config),
    flush_bindings(Va),
    ok = agent_bridge_client:get_binding(Va),
    receive
        {agent_bridge, Va, {binding, #{bound := [_ | _]}}} -> ok
    after evatar_test_time:guard() -> ct:fail(no_binding)
    end,
    ok = agent_bridge_client:close(Va).

flush_bindings(Va) ->
    receive {agent_bridge, Va, {binding, _}} -> flush_bindings(Va)
    after 0 -> ok
    end.

recv_doc_skipping_acks(S) ->
    case recv_doc(S) of
        {control, {ack, _}} -> recv_doc_skipping_acks(S);
        Doc -> Doc
    end.

%% A new description from the Avatar rebinds; the new component is reachable.
re_register(Config) ->
    {Va, Av} = bound_pair(Config),
    {error, #{body := #{type := <<"UnknownReceiver">>}}} =
        agent_bridge_client:request(Va, door_request(), evatar_test_time:guard()),
    Av ! {describe, avatar_description(<<"av">>, true)},
    #{bound := Bound} = wait_binding(Va, fun(#{bound := B}) -> length(B) >= 2 end),
    true = lists:any(fun(#{provider := #{component := C}}) -> C =:= <<"Door01">> end, Bound),
    {ok, #{context := feedback}} = agent_bridge_client:request(Va, door_request(), evatar_test_time:guard()),
    ok = agent_bridge_client:close(Va).

%% Deleting a pairing closes its connections with a reason.
pairing_deleted(Config) ->
    {Va, _Av} = bound_pair(Config),
    ok = evatar:delete_pairing(?config(pairing, Config)),
    receive
        {agent_bridge, Va, {closed, {refused, <<"PairingDeleted">>, <<"the pairing was deleted">>}}} -> ok
    after evatar_test_time:guard() -> ct:fail(not_closed)
    end.

%% ---------------------------------------------------------------------------
%% Backpressure
%% ---------------------------------------------------------------------------

%% A VA that never reads while its Avatar streams: the bounded outbound
%% queue overflows and the connection is closed (SlowConsumer); the Avatar
%% and the node carry on.
never_reading_client(Config) ->
    Small = ?config(small, Config),
    S = joined_raw([{addr, Small} | Config], agent, <<"va">>, ?VA_CRED, [{recbuf, 4096}]),
    ok = gen_tcp:send(S, bil:encode_description(va_description(<<"va">>))),
    {ok, Av} = client([{addr, Small} | Config], avatar, <<"av">>),
    ok = agent_bridge_client:describe(Av, avatar_description(<<"av">>, false)),
    Payload = binary:copy(<<"x">>, 2000),
    N = 5000,
    [ok = agent_bridge_client:send(Av, sensor(I, Payload)) || I <- lists:seq(1, N)],
    %% Only now read: what was queued arrives, then the close.
    {Frames, Codes} = drain(S, 0, []),
    ct:log("read ~b of ~b frames before the close; refusals ~p", [Frames, N, Codes]),
    true = Frames < N,
    true = Codes =:= [] orelse Codes =:= [<<"SlowConsumer">>],
    ok = agent_bridge_client:close(Av).

%% A client that floods while its pairing cannot keep up: the connection
%% stops reading, so no more of its signals wait in the pairing's mailbox
%% than the watermark lets through; after the pairing resumes every signal
%% is delivered.
%%
%% The bound holds for any scheduling: the connection forwards a frame
%% only after a check that found the pairing's mailbox at or below the
%% watermark (W, every message counted), and after such a check at most
%% the frame in hand and `active_n' (N) more can still come from the
%% socket and its own mailbox. So the pairing never holds more than
%% W + N + 1 of this client's signals. Only those are counted: timers and
%% other processes' messages (which a loaded machine leaves there longer)
%% are not the bridge's to bound, and they only make it stop sooner. A
%% bridge that kept reading would pass the bound within a few frames of
%% the 3000 sent.
flooding_client(Config) ->
    Small = ?config(small, Config),
    C2 = [{addr, Small} | Config],
    {ok, Av} = client(C2, avatar, <<"av">>),
    ok = agent_bridge_client:describe(Av, avatar_description(<<"av">>, false)),
    {ok, Va} = client(C2, agent, <<"va">>),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    _ = wait_binding(Va, fun(#{bound := B}) -> B =/= [] end),
    Pid = evatar_registry:whereis_name(?config(pairing, Config)),
    ok = sys:suspend(Pid),
    N = 3000,
    Self = self(),
    Flooder = spawn_link(fun() ->
                                 [ok = agent_bridge_client:send(Av, sensor(I, <<"x">>))
                                  || I <- lists:seq(1, N)],
                                 Self ! flooded
                         end),
    Watermark = 20,
    ActiveN = 4,
    %% Past the watermark the connection reads no more.
    ok = until(fun() -> queue_len(Pid) > Watermark end),
    %% The reader is paused; more waiting does not let more in.
    Peak = lists:max([begin timer:sleep(20), signals_waiting(Pid, <<"av">>) end
                      || _ <- lists:seq(1, 25)]),
    ct:log("the client's signals in the pairing's mailbox: at most ~b (watermark ~b, "
           "active_n ~b; ~b messages in all at the end)",
           [Peak, Watermark, ActiveN, queue_len(Pid)]),
    true = Peak =< Watermark + ActiveN + 1,
    ok = sys:resume(Pid),
    receive flooded -> ok after evatar_test_time:guard() -> ct:fail(flooder_stuck) end,
    N = length(collect_sensor(Va, N, [])),
    unlink(Flooder),
    ok = agent_bridge_client:close(Va),
    ok = agent_bridge_client:close(Av).

%% A connection that keeps up (nothing waiting in its mailbox, its pairing
%% below the watermark) never lets its socket go passive: it tops the
%% socket's count up as it reads, so the runtime keeps polling the socket
%% from its schedulers (docs/protocol.md, "Backpressure"). Re-arming after
%% a passive notice, as before, shows a notice every 32 frames here.
keeping_up_never_passive(Config) ->
    S = joined_raw(Config, avatar, <<"av">>, ?AV_CRED),
    ok = gen_tcp:send(S, bil:encode_description(avatar_description(<<"av">>, false))),
    {ok, Va} = client(Config, agent, <<"va">>),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    _ = wait_binding(Va, fun(#{bound := B}) -> B =/= [] end),
    {ok, Local} = inet:port(S),
    [Conn] = [Owner || P <- erlang:ports(), erlang:port_info(P, name) =:= {name, "tcp_inet"},
                       inet:peername(P) =:= {ok, {{127, 0, 0, 1}, Local}},
                       {connected, Owner} <- [erlang:port_info(P, connected)]],
    N = 300,
    1 = erlang:trace(Conn, true, ['receive']),
    Frame = fun raw_sensor_frame/1,
    %% One frame at a time, each delivered before the next is sent.
    _ = [begin
             ok = gen_tcp:send(S, Frame(I)),
             [_] = collect_sensor(Va, 1, [])
         end || I <- lists:seq(1, N)],
    1 = erlang:trace(Conn, false, ['receive']),
    Passive = count_passive(erlang:trace_delivered(Conn), 0),
    ct:log("passive notices while ~b frames were read: ~b", [N, Passive]),
    0 = Passive,
    ok = agent_bridge_client:close(Va),
    ok = gen_tcp:close(S).

%% A client that sends faster than `max_read_rate' is read at that rate
%% (with a burst of one second's worth): its frames wait in TCP's buffers,
%% and every one of them is delivered, in order, none refused
%% (docs/protocol.md section 8). The bucket bounds what can have been read
%% by time t to Rate * t + Rate, plus what the socket had let in before it
%% went passive (active_n) and one top-up's count: a lower bound on the
%% time N frames take, which a loaded machine can only lengthen.
paced_client_read_at_its_rate(Config) ->
    C2 = [{addr, ?config(paced, Config)} | Config],
    S = joined_raw(C2, avatar, <<"av">>, ?AV_CRED),
    ok = gen_tcp:send(S, bil:encode_description(avatar_description(<<"av">>, false))),
    {ok, Va} = client(C2, agent, <<"va">>),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    _ = wait_binding(Va, fun(#{bound := B}) -> B =/= [] end),
    Frame = fun raw_sensor_frame/1,
    N = 400,
    Rate = ?PACED_RATE,
    T0 = erlang:monotonic_time(millisecond),
    Sender = spawn_link(fun() -> [ok = gen_tcp:send(S, Frame(I)) || I <- lists:seq(1, N)] end),
    Got = collect_sensor(Va, N, []),
    Took = erlang:monotonic_time(millisecond) - T0,
    Bound = (N - Rate - 32 - 16) * 1000 div Rate,
    ct:log("~b frames at max_read_rate ~b: delivered in ~b ms (at least ~b ms)",
           [N, Rate, Took, Bound]),
    Expected = [integer_to_binary(I) || I <- lists:seq(1, N)],
    Expected = [I || {_, I} <- Got],
    true = Took >= Bound,
    unlink(Sender),
    ok = agent_bridge_client:close(Va),
    ok = gen_tcp:close(S).

%% The trace's tcp_passive messages, all of them: trace_delivered's
%% answer comes after every trace message of the traced process.
count_passive(Ref, K) ->
    receive
        {trace, _, 'receive', {tcp_passive, _}} -> count_passive(Ref, K + 1);
        {trace, _, 'receive', _} -> count_passive(Ref, K);
        {trace_delivered, _, Ref} -> K
    after evatar_test_time:guard() -> ct:fail(trace_not_delivered)
    end.

%% ---------------------------------------------------------------------------
%% Listener keeper
%% ---------------------------------------------------------------------------

%% A configured listener whose port is taken does not stop the bridge: its
%% keeper retries with growing delays, reports a crash loop from the third
%% failure, and listens (clients join) once the port is free.
listener_port_taken_retries(Config) ->
    {ok, Taken} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}, {reuseaddr, true}]),
    {ok, Port} = inet:port(Taken),
    ok = logger:add_handler(crash_loop_probe, ?MODULE, #{config => #{pid => self()}}),
    Opts = #{ip => {127, 0, 0, 1}, port => Port,
             restart => #{min_ms => 50, max_ms => 400, loop_after => 3}},
    %% As agent_bridge_sup starts a listener of the configuration.
    {ok, Keeper} = supervisor:start_child(agent_bridge_sup,
                                          agent_bridge_sup:listener_spec(kept, Opts)),
    try
        {error, not_found} = agent_bridge:address(kept),
        receive
            {crash_loop, #{listener := kept, crashes := N}} -> true = N >= 3
        after evatar_test_time:guard() -> ct:fail(no_crash_loop_report)
        end,
        %% Each failure doubles the delay, up to the maximum.
        #{state := waiting, failures := Failures, next_delay_ms := Next} =
            agent_bridge_listener_keeper:status(Keeper),
        true = Failures >= 3,
        true = Next >= 400,
        ok = gen_tcp:close(Taken),
        ok = until(fun() -> agent_bridge:address(kept) =:= {ok, {{127, 0, 0, 1}, Port}} end),
        #{state := running, starts := 1} = agent_bridge_listener_keeper:status(Keeper),
        {ok, C} = client([{addr, {{127, 0, 0, 1}, Port}} | Config], agent, <<"va">>),
        ok = agent_bridge_client:close(C)
    after
        ok = logger:remove_handler(crash_loop_probe),
        _ = agent_bridge:stop_listener(kept)
    end.

%% ---------------------------------------------------------------------------
%% Port connector
%% ---------------------------------------------------------------------------

%% An external program joins as an Avatar over stdin/stdout, answers a
%% request, has its stderr logged, and is restarted with back-off when it
%% exits.
port_round_trip(Config) ->
    case os:find_executable("python3") of
        false -> {skip, no_python3};
        Python -> port_round_trip(Config, Python)
    end.

port_round_trip(Config, Python) ->
    #{level := Level} = logger:get_primary_config(),
    ok = logger:set_primary_config(level, notice),
    Script = filename:join(?config(data_dir, Config), "port_avatar.py"),
    ok = logger:add_handler(port_test, ?MODULE, #{config => #{pid => self()}}),
    {ok, Va} = client(Config, agent, <<"va">>),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    {ok, Keeper} = agent_bridge:start_port(port_test,
                                           #{command => Python,
                                             args => [Script, binary_to_list(?config(pairing, Config)),
                                                      binary_to_list(?AV_CRED)],
                                             backoff_min => 50, backoff_max => 200}),
    _ = wait_binding(Va, fun(#{bound := B}) -> B =/= [] end),
    {ok, #{context := feedback, sender := <<"Light01">>}} =
        agent_bridge_client:request(Va, light_request(), evatar_test_time:guard()),
    receive {stderr_line, <<"port_avatar: answered", _/binary>>} -> ok
    after evatar_test_time:guard() -> ct:fail(no_stderr_logged)
    end,
    %% The script exits after its first answer; the keeper starts it again.
    ok = until(fun() -> agent_bridge_port:runs(Keeper) >= 2 end),
    ok = agent_bridge:stop_port(port_test),
    ok = logger:remove_handler(port_test),
    ok = logger:set_primary_config(level, Level),
    ok = agent_bridge_client:close(Va).

%% logger handler callback: forwards the port connector's stderr lines and
%% crash loop reports (listener_port_taken_retries).
log(#{msg := {report, #{what := program_stderr, line := Line}}}, #{config := #{pid := Pid}}) ->
    Pid ! {stderr_line, Line};
log(#{msg := {report, #{what := crash_loop} = Report}}, #{config := #{pid := Pid}}) ->
    Pid ! {crash_loop, Report};
log(_, _) ->
    ok.

%% ---------------------------------------------------------------------------
%% A busy pairing (made busy for real: its process suspended)
%% ---------------------------------------------------------------------------

%% A Hello to a pairing that does not answer within the call timeout gets
%% Refused Busy (the connection process does not crash on the timeout);
%% the join the pairing gets to later ends with that connection.
busy_pairing_refuses_hello(Config) ->
    Pid = suspend_pairing(Config, 300),
    S = raw_connect(Config),
    ok = gen_tcp:send(S, hello(Config, agent, <<"va">>, ?VA_CRED)),
    ok = expect_refused(S, <<"Busy">>),
    ok = sys:resume(Pid),
    ok = until(fun() -> registered_entities(Config) =:= [] end),
    {ok, C} = client(Config, agent, <<"va">>),
    ok = agent_bridge_client:close(C).

%% A description sent while the pairing is busy gets an Error signal
%% saying so, on a connection that stays up; the description, still
%% queued, is applied when the pairing goes on, and the report follows.
busy_pairing_description(Config) ->
    S = joined_raw(Config, agent, <<"va">>, ?VA_CRED),
    Pid = suspend_pairing(Config, 300),
    ok = gen_tcp:send(S, bil:encode_description(va_description(<<"va">>))),
    {signal, #{context := error, body := #{type := <<"DescriptionRefused">>,
                                           parameters := [{<<"Message">>, Message}]}}} =
        recv_doc(S),
    {match, _} = re:run(Message, "busy"),
    ok = sys:resume(Pid),
    {control, {binding, #{entities := [<<"va">>]}}} = recv_doc(S),
    ok = gen_tcp:send(S, bil_control:encode({bye, <<>>})),
    {control, {bye, _}} = recv_doc(S),
    {error, closed} = gen_tcp:recv(S, 0, evatar_test_time:guard()).

%% A Bye is answered while the pairing cannot answer anything (the call
%% timeout here is ten minutes: a connection waiting for the pairing would
%% not answer); the entity leaves once the pairing goes on.
busy_pairing_bye(Config) ->
    S = joined_raw(Config, agent, <<"va">>, ?VA_CRED),
    Pid = suspend_pairing(Config, 600000),
    ok = gen_tcp:send(S, bil_control:encode({bye, <<>>})),
    {control, {bye, _}} = recv_doc(S),
    {error, closed} = gen_tcp:recv(S, 0, evatar_test_time:guard()),
    true = suspended(Pid),
    ok = sys:resume(Pid),
    ok = until(fun() -> registered_entities(Config) =:= [] end).

%% Operator calls to a busy pairing return `{error, busy}' (or show it
%% unavailable) instead of raising; a delete goes through once it can.
busy_pairing_operator(Config) ->
    P = ?config(pairing, Config),
    Pid = suspend_pairing(Config, 300),
    {error, busy} = evatar:stats(P),
    {error, busy} = evatar:bindings(P),
    {error, busy} = evatar:print_registry(P),
    [#{state := unavailable}] = [S || #{id := Id} = S <- evatar:pairings(), Id =:= P],
    {error, busy} = evatar:delete_pairing(P),
    Ref = monitor(process, Pid),
    ok = sys:resume(Pid),
    receive {'DOWN', Ref, process, Pid, normal} -> ok after evatar_test_time:guard() -> ct:fail(not_deleted) end.

suspend_pairing(Config, CallTimeout) ->
    ok = application:set_env(evatar, call_timeout, CallTimeout),
    Pid = evatar_registry:whereis_name(?config(pairing, Config)),
    ok = sys:suspend(Pid),
    Pid.

%% A suspended process still answers system messages.
suspended(Pid) ->
    {status, Pid, _, [_PDict, SysState | _]} = sys:get_status(Pid),
    SysState =:= suspended.

registered_entities(Config) ->
    {ok, Registry} = evatar:registry(?config(pairing, Config)),
    Registry.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

client_opts(Config, Role, Entity) ->
    evatar_test_fixtures:client_opts(?config(pairing, Config), Role, Entity).

client(Config, Role, Entity) ->
    evatar_test_fixtures:client(?config(addr, Config), ?config(pairing, Config), Role, Entity).

hello(Config, Role, Entity, Cred) ->
    evatar_test_fixtures:hello(?config(pairing, Config), Role, Entity, Cred, 1).

raw_connect(Config) -> raw_connect(Config, []).

raw_connect(Config, Extra) ->
    {Ip, Port} = ?config(addr, Config),
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {packet, 4}, {active, false} | Extra]),
    S.

joined_raw(Config, Role, Entity, Cred) -> joined_raw(Config, Role, Entity, Cred, []).

joined_raw(Config, Role, Entity, Cred, Extra) ->
    S = raw_connect(Config, Extra),
    ok = gen_tcp:send(S, hello(Config, Role, Entity, Cred)),
    {control, {welcome, _}} = recv_doc(S),
    S.

recv_doc(S) -> evatar_test_fixtures:recv_doc(S, evatar_test_time:guard()).

recv_raw_doc(S) ->
    {ok, <<Len:32>>} = gen_tcp:recv(S, 4, evatar_test_time:guard()),
    {ok, Frame} = gen_tcp:recv(S, Len, evatar_test_time:guard()),
    {ok, Doc} = bil_control:parse_frame(Frame, #{}),
    Doc.

expect_refused(S, Code) ->
    {control, {refused, #{code := Code, message := Message}}} = recv_doc(S),
    true = is_binary(Message) andalso Message =/= <<>>,
    {error, closed} = gen_tcp:recv(S, 0, evatar_test_time:guard()),
    ok.

refused_hello(Config, Hello, Code) ->
    S = raw_connect(Config),
    ok = gen_tcp:send(S, Hello),
    expect_refused(S, Code).

%% Reads until the server closes; counts signal frames, collects Refused codes.
drain(S, Frames, Codes) ->
    case gen_tcp:recv(S, 0, 10000) of
        {ok, Frame} ->
            case bil_control:parse_frame(Frame, #{}) of
                {ok, {control, {refused, #{code := Code}}}} -> drain(S, Frames, [Code | Codes]);
                {ok, _} -> drain(S, Frames + 1, Codes)
            end;
        {error, closed} ->
            {Frames, Codes}
    end.

queue_len(Pid) ->
    {message_queue_len, N} = erlang:process_info(Pid, message_queue_len),
    N.

%% The signals of entity Entity waiting in a pairing's mailbox
%% (evatar:send/2's casts).
signals_waiting(Pid, Entity) ->
    {messages, Ms} = erlang:process_info(Pid, messages),
    length([M || {'$gen_cast', {signal, E, _}} = M <- Ms, E =:= Entity]).


%% A VA and an Avatar bound to each other; the Avatar runs a responder.
bound_pair(Config) ->
    Av = start_responder(Config, <<"av">>),
    {ok, Va} = client(Config, agent, <<"va">>),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    _ = wait_binding(Va, fun(#{bound := B}) -> B =/= [] end),
    {Va, Av}.

wait_binding(Va, Pred) ->
    evatar_test_fixtures:wait_binding(Va, Pred, evatar_test_time:guard()).

collect_sensor(_Va, 0, Acc) ->
    lists:reverse(Acc);
collect_sensor(Va, N, Acc) ->
    receive
        {agent_bridge, Va, {signal, #{context := sensor_data, seq := Seq,
                                      body := #{parameters := Params}}}} ->
            {_, I} = lists:keyfind(<<"N">>, 1, Params),
            collect_sensor(Va, N - 1, [{Seq, I} | Acc])
    after evatar_test_time:guard() -> lists:reverse(Acc)
    end.

%% An Avatar client that answers every request with a feedback, streams on
%% demand, and can be told to go quiet or to describe itself again.
start_responder(Config, Entity) ->
    Self = self(),
    Pid = spawn_link(fun() ->
                             {ok, C} = client(Config, avatar, Entity),
                             ok = agent_bridge_client:describe(C, avatar_description(Entity, false)),
                             Self ! {responder, self()},
                             responder(C, true)
                     end),
    receive {responder, Pid} -> Pid after evatar_test_time:guard() -> ct:fail(responder_not_started) end.

responder(C, Answer) ->
    receive
        {agent_bridge, C, {signal, #{context := request, id := Id, sender := From,
                                     receiver := To, body := Body}}} when Answer ->
            ok = agent_bridge_client:send(C, #{context => feedback, sender => To, receiver => From,
                                               in_reply_to => Id,
                                               body => Body#{parameters => [{<<"Done">>, <<"yes">>}]}}),
            responder(C, Answer);
        mute ->
            responder(C, false);
        {stream, N} ->
            [ok = agent_bridge_client:send(C, sensor(I, <<"21.5">>)) || I <- lists:seq(1, N)],
            responder(C, Answer);
        {describe, D} ->
            ok = agent_bridge_client:describe(C, D),
            responder(C, Answer);
        {agent_bridge, C, {closed, _}} ->
            ok;
        _ ->
            responder(C, Answer)
    end.

start_bystander(Addr) ->
    Pairing = <<"bystander">>,
    {ok, _} = evatar_test_fixtures:create_pairing(Pairing, #{}),
    Config = [{addr, Addr}, {pairing, Pairing}],
    Parent = self(),
    %% The bystander's clients belong to a long-lived process, not to the
    %% init_per_suite process.
    Holder = spawn(fun() ->
                           {Va, Av} = bound_pair(Config),
                           Parent ! {bystander, Va, Av},
                           bystander_holder(Va, undefined)
                   end),
    receive {bystander, Va, Av} -> {Va, Av, Holder} after evatar_test_time:guard() -> ct:fail(no_bystander) end.

%% Keeps the bystander VA's owner messages: a close names its reason, so a
%% failed round trip says why the node dropped a healthy client (it once
%% was the lone node fencing itself under load, fixed in bd99361).
bystander_holder(Va, Closed) ->
    receive
        stop -> ok;
        {agent_bridge, Va, {closed, Reason}} -> bystander_holder(Va, Reason);
        {why_closed, From} -> From ! {why_closed, Closed}, bystander_holder(Va, Closed);
        _ -> bystander_holder(Va, Closed)
    end.

bystander_round_trip(Config) ->
    {Va, _Av, Holder} = ?config(bystander, Config),
    case agent_bridge_client:request(Va, light_request(), 5000) of
        {ok, #{context := feedback}} ->
            ok;
        Other ->
            Holder ! {why_closed, self()},
            Why = receive {why_closed, W} -> W after evatar_test_time:guard() -> unknown end,
            ct:fail({bystander_round_trip, Other, {closed, Why}})
    end.

light_request() ->
    #{sender => <<"LightEmulator01">>, receiver => <<"Light01">>,
      body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                parameters => [{<<"Light">>, <<"yes">>}]}}.

door_request() ->
    #{sender => <<"DoorEmulator01">>, receiver => <<"Door01">>,
      body => #{category => <<"ACTUATOR">>, type => <<"OpenDoor">>, parameters => []}}.

%% Sensor frame I as a raw client sends it, its SignalID I.
raw_sensor_frame(I) ->
    bil:encode_signal((sensor(I, <<"20">>))#{id => integer_to_binary(I), in_reply_to => undefined,
                                             timestamp => 0, seq => undefined, epoch => undefined}).

sensor(I, Value) ->
    #{context => sensor_data, sender => <<"Thermo01">>, receiver => <<"ThermoEmulator01">>,
      body => #{category => <<"SENSOR">>, type => <<"Temperature">>,
                parameters => [{<<"Value">>, Value}, {<<"N">>, integer_to_binary(I)}]}}.

va_description(Id) ->
    C = fun evatar_test_fixtures:component/3,
    evatar_test_fixtures:description(
      Id, agent, <<"TEST VA">>, <<"EmulatorDescription">>,
      [C(<<"LightEmulator01">>, [{<<"BEHAVIOUR">>, <<"Light">>}],
         [{<<"ACTUATOR">>, <<"TurnLightOn">>}, {<<"ACTUATOR">>, <<"Dim">>}]),
       C(<<"DoorEmulator01">>, [{<<"BEHAVIOUR">>, <<"Door">>}], [{<<"ACTUATOR">>, <<"OpenDoor">>}]),
       C(<<"ThermoEmulator01">>, [{<<"SENSOR">>, <<"Temperature">>}], [])]).

%% The suites' Avatar body, with a door when WithDoor.
avatar_description(Id, WithDoor) ->
    #{components := Cs} = D = evatar_test_fixtures:avatar_description(Id),
    Door = [evatar_test_fixtures:component(<<"Door01">>, [{<<"ACTUATOR">>, <<"OpenDoor">>}], [])
            || WithDoor],
    D#{components := Cs ++ Door}.
