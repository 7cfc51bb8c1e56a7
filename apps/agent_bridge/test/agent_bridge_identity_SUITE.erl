%% @doc Attacks on device identity and on the per-pairing limits, over real
%% sockets against a real node (issue 15, sections 3 and 4): a holder of
%% the Avatar credential tries to take a detached device's EntityID, to
%% fill every Avatar slot, to pass for EVATAR and to forge its Timeout
%% feedback; a VA holds 100,000 requests open; an Avatar uses 60,000-
%% character ids. Each gets a clear refusal, and after each case a
%% bystander pairing still does a request round trip.
-module(agent_bridge_identity_SUITE).

-include_lib("common_test/include/ct.hrl").

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1, init_per_testcase/2,
         end_per_testcase/2]).
-export([take_detached_entity/1, fill_avatar_slots/1, pass_for_evatar/1,
         forge_timeout_feedback/1, hold_100000_requests/1, ids_of_60000_characters/1]).

-define(VA_CRED, evatar_test_fixtures:va_credential()).
-define(AV_CRED, evatar_test_fixtures:avatar_credential()).
-define(LAMP_CRED, <<"lamp-own-secret">>).

suite() -> [{timetrap, {minutes, 5}}].

all() ->
    [take_detached_entity, fill_avatar_slots, pass_for_evatar, forge_timeout_feedback,
     hold_100000_requests, ids_of_60000_characters].

init_per_suite(Config) ->
    %% A lone node fences its pairings after a scheduling gap of suspect_ms
    %% (250 ms): on a loaded machine, 100,000 signals can cause one. These
    %% cases are about identity and limits, not fencing.
    ok = application:set_env(evatar, suspect_ms, 10000),
    ok = evatar_test_node:start([]),
    %% The listener's guard (rate, failure delay, lockout) is tested by
    %% agent_bridge_attack_SUITE; here every refusal must come from the pairing.
    %% A connection's read rate (max_read_rate, 1,000 frames/s by default) is
    %% tested by agent_bridge_SUITE's paced_client_read_at_its_rate; here it
    %% would only pace hold_100000_requests to 100 s.
    Addr = evatar_test_node:listen(identity, #{conn => #{handshake_timeout => evatar_test_time:ms(2000),
                                                               linger => 100,
                                                               max_read_rate => infinity},
                                                     handshake => #{rate => infinity,
                                                                    failure_delay => 0,
                                                                    max_failure_delay => 0,
                                                                    lockout => 0}}),
    Bystander = start_bystander(Addr),
    [{addr, Addr}, {bystander, Bystander} | Config].

end_per_suite(Config) ->
    {_, _, Holder} = ?config(bystander, Config),
    Holder ! stop,
    ok = evatar:delete_pairing(<<"identity-bystander">>),
    ok = application:unset_env(evatar, suspect_ms),
    evatar_test_node:stop([identity], [agent_bridge]).

%% Every pairing of these cases lists the device `lamp' with its own
%% credential, and lets unlisted ids join with the role credentials.
init_per_testcase(Case, Config) ->
    Pairing = atom_to_binary(Case),
    {ok, _} = evatar:create_pairing(
                Pairing, #{agent_credential => ?VA_CRED, avatar_credential => ?AV_CRED,
                           identities => [#{entity => <<"lamp">>, role => avatar,
                                            credential => ?LAMP_CRED}],
                           unlisted_ids => role_credential,
                           max_avatars => 4, feedback_timeout => 600000,
                           join_timeout => 20000}),
    [{pairing, Pairing} | Config].

end_per_testcase(_Case, Config) ->
    _ = evatar:delete_pairing(?config(pairing, Config)),
    %% The node and the other pairings are unaffected.
    {Va, _, _} = ?config(bystander, Config),
    {ok, #{context := feedback}} = agent_bridge_client:request(Va, light_request(), evatar_test_time:guard()),
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% The device `lamp' is detached (its version 2 connection went); the
%% Avatar credential does not join as `lamp', and the device resumes.
take_detached_entity(Config) ->
    Pairing = ?config(pairing, Config),
    S = raw_connect(Config),
    ok = gen_tcp:send(S, hello(Config, avatar, <<"lamp">>, ?LAMP_CRED, 2)),
    {control, {welcome, #{session_id := Session}}} = recv_doc(S),
    ok = gen_tcp:send(S, bil:encode_description(lamp_description(<<"lamp">>))),
    {control, {binding, _}} = recv_doc(S),
    ok = gen_tcp:close(S),
    ok = evatar_test_wait:until(fun() -> not attached(Pairing, <<"lamp">>) end),
    [<<"BadCredential">> = refused_code(Config, hello(Config, avatar, <<"lamp">>, Cred, V))
     || Cred <- [?AV_CRED, ?VA_CRED, <<>>], V <- [1, 2]],
    {ok, Registry} = evatar:registry(Pairing),
    [#{entity := <<"lamp">>, registered := true}] = Registry,
    S2 = raw_connect(Config),
    ok = gen_tcp:send(S2, bil_control:encode(
                            {resume, #{pairing => Pairing, role => avatar, entity_id => <<"lamp">>,
                                       credential => ?LAMP_CRED, protocol_version => 2,
                                       session_id => Session, received => 0, epoch => 1}})),
    {control, {welcome, #{ha := #{resumed := true}}}} = recv_doc(S2),
    ok = gen_tcp:close(S2).

%% With identities and no unlisted ids, the Avatar credential joins no
%% slot at all; with unlisted ids it fills at most max_avatars, and the
%% listed device still has to present its own credential.
fill_avatar_slots(Config) ->
    Pairing = <<"fill_avatar_slots_listed_only">>,
    {ok, _} = evatar:create_pairing(
                Pairing, #{agent_credential => ?VA_CRED, avatar_credential => ?AV_CRED,
                           identities => [#{entity => <<"lamp">>, role => avatar,
                                            credential => ?LAMP_CRED}]}),
    Listed = [{pairing, Pairing} | Config],
    [<<"BadCredential">> = refused_code(Listed, hello(Listed, avatar, Id, ?AV_CRED, 1))
     || I <- lists:seq(1, 70), Id <- [<<"slot-", (integer_to_binary(I))/binary>>]],
    {ok, []} = evatar:registry(Pairing),
    S = joined_raw(Listed, avatar, <<"lamp">>, ?LAMP_CRED),
    ok = gen_tcp:close(S),
    ok = evatar:delete_pairing(Pairing),
    %% The case's pairing allows unlisted ids: they stop at max_avatars (4).
    Held = [joined_raw(Config, avatar, <<"slot-", (integer_to_binary(I))/binary>>, ?AV_CRED)
            || I <- lists:seq(1, 4)],
    <<"TooManyEntities">> = refused_code(Config, hello(Config, avatar, <<"slot-5">>, ?AV_CRED, 1)),
    [ok = gen_tcp:close(H) || H <- Held].

%% Ids that read as EVATAR are refused: as an EntityID at the Hello, as a
%% ComponentID in a description; what EVATAR says carries Origin EVATAR.
pass_for_evatar(Config) ->
    [<<"ReservedId">> = refused_code(Config, hello(Config, avatar, Id, ?AV_CRED, 1))
     || Id <- [<<"EVATAR">>, <<"evatar">>, <<"E-V-A-T-A-R">>, <<" Evatar ">>]],
    S = joined_raw(Config, avatar, <<"mallory">>, ?AV_CRED),
    Desc = lamp_description(<<"mallory">>),
    [C | _] = maps:get(components, Desc),
    ok = gen_tcp:send(S, bil:encode_description(Desc#{components := [C#{id := <<"Evatar">>}]})),
    {signal, #{sender := <<"EVATAR">>, origin := evatar, context := error,
               body := #{type := <<"DescriptionRefused">>, parameters := Params}}} = recv_doc(S),
    {_, Message} = lists:keyfind(<<"Message">>, 1, Params),
    ct:log("DescriptionRefused: ~s", [Message]),
    {match, _} = re:run(Message, "reserved"),
    ok = gen_tcp:close(S).

%% An Avatar that provides the VA's service answers a request with a
%% Feedback made to look like EVATAR's Timeout: with the Origin mark it is
%% refused; without it, it reaches the VA as the Avatar's own (its Sender
%% is the Avatar's component, no Origin), while EVATAR's real Timeout
%% carries Origin EVATAR.
forge_timeout_feedback(Config) ->
    {ok, Va} = client(Config, agent, <<"va">>, ?VA_CRED),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    S = joined_raw(Config, avatar, <<"mallory">>, ?AV_CRED),
    ok = gen_tcp:send(S, bil:encode_description(lamp_description(<<"mallory">>))),
    _ = evatar_test_fixtures:wait_binding(Va, fun(#{bound := B}) -> B =/= [] end, evatar_test_time:guard()),
    ok = agent_bridge_client:send(Va, (light_request())#{id => <<"req-1">>,
                                                           context => request}),
    Req = recv_until(S, fun({signal, #{context := request}}) -> true; (_) -> false end),
    {signal, #{id := <<"req-1">>, sender := VaComp, receiver := MyComp}} = Req,
    Forged = #{id => <<"forged-1">>, context => feedback, sender => MyComp, receiver => VaComp,
               in_reply_to => <<"req-1">>, timestamp => 1, seq => undefined, epoch => undefined,
               body => #{category => <<"EVATAR">>, type => <<"Timeout">>,
                         parameters => [{<<"Message">>, <<"no feedback">>}]}},
    ok = gen_tcp:send(S, bil:encode_signal(Forged#{origin => evatar})),
    {signal, #{context := error, origin := evatar, in_reply_to := <<"forged-1">>,
               body := #{type := <<"BadSignal">>}}} =
        recv_until(S, fun({signal, #{context := error}}) -> true; (_) -> false end),
    %% Without the mark it is the Avatar's feedback, and looks it.
    ok = gen_tcp:send(S, bil:encode_signal(Forged)),
    #{sender := MyComp} = Seen =
        evatar_test_fixtures:wait_signal(Va, fun(#{id := Id}) -> Id =:= <<"forged-1">> end,
                                           10000),
    false = maps:is_key(origin, Seen),
    ok = gen_tcp:close(S),
    %% A request left open when its provider goes: EVATAR's own feedback.
    ok = agent_bridge_client:close(Va).

%% 100,000 requests to an Avatar that never answers: max_open_requests
%% (1,024) stay open, every other one is refused with TooManyRequests, and
%% each request is either forwarded to the Avatar or refused, exactly once.
%% The requests go in batches of 1,000 frames per write.
hold_100000_requests(Config) ->
    Pairing = ?config(pairing, Config),
    Va = joined_raw(Config, agent, <<"va">>, ?VA_CRED),
    ok = gen_tcp:send(Va, bil:encode_description(va_description(<<"va">>))),
    S = joined_raw(Config, avatar, <<"mute">>, ?AV_CRED),
    ok = gen_tcp:send(S, bil:encode_description(lamp_description(<<"mute">>))),
    ok = evatar_test_wait:until(
           fun() -> {ok, #{bound := B}} = evatar:bindings(Pairing), B =/= [] end),
    %% Both sockets are read by processes of their own, so the bridge never
    %% drops either as a slow consumer; each reports the SignalIDs it saw:
    %% the Avatar's the requests forwarded, the VA's the requests refused.
    N = 100000,
    Open = 1024,
    Self = self(),
    %% Both sockets carry raw bytes from here on, framed by
    %% agent_bridge_frame, so that one write to the VA's holds a batch.
    ok = inet:setopts(S, [{packet, raw}]),
    ok = inet:setopts(Va, [{packet, raw}]),
    Mute = spawn_link(fun() -> receive go -> ok end,
                               Self ! {forwarded, ids(S, <<"SignalID">>,
                                                      <<"RequestAwaitingFeedback">>, Open)},
                               receive stop -> ok end
                      end),
    ok = gen_tcp:controlling_process(S, Mute),
    Mute ! go,
    [Template] = [bil:encode_signal(
                    (light_request())#{id => <<"@REQ@">>, context => request,
                                       in_reply_to => undefined, timestamp => 1,
                                       seq => undefined, epoch => undefined})],
    [Head, Tail] = binary:split(iolist_to_binary(Template), <<"@REQ@">>),
    %% The reader owns the VA's socket: it stays until the end, or the
    %% socket would close with it and the VA leave the pairing.
    Reader = spawn_link(fun() -> receive go -> ok end,
                                 Self ! {refused, ids(Va, <<"InReplyTo">>,
                                                      <<"<ServiceType>TooManyRequests<">>,
                                                      N - Open)},
                                 receive stop -> ok end
                        end),
    ok = gen_tcp:controlling_process(Va, Reader),
    Reader ! go,
    Frame = fun(I) -> agent_bridge_frame:encode([Head, integer_to_binary(I), Tail]) end,
    [ok = gen_tcp:send(Va, [Frame(I) || I <- lists:seq(B, min(N, B + 999))])
     || B <- lists:seq(1, N, 1000)],
    Forwarded = receive {forwarded, F} -> F end,
    Refused = receive {refused, R} -> R end,
    ct:log("~b requests: ~b forwarded, ~b refused with TooManyRequests",
           [N, length(Forwarded), length(Refused)]),
    %% Every request once, forwarded or refused; none twice.
    All = lists:sort([binary_to_integer(I) || I <- Forwarded ++ Refused]),
    All = lists:seq(1, N),
    NRefused = N - Open,
    {ok, #{pending := Open, errors := #{<<"TooManyRequests">> := NRefused}}} =
        evatar:stats(Pairing),
    [begin unlink(P), exit(P, kill) end || P <- [Mute, Reader]],
    ok.

%% 60,000-character ids: an EntityID at the Hello, a ComponentID in a
%% description, a SignalID; each is refused, and another entity's Binding
%% report stays small.
ids_of_60000_characters(Config) ->
    Long = binary:copy(<<"x">>, 60000),
    <<"IdTooLong">> = refused_code(Config, hello(Config, avatar, Long, ?AV_CRED, 1)),
    {ok, Va} = client(Config, agent, <<"va">>, ?VA_CRED),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    _ = evatar_test_fixtures:wait_binding(Va, fun(_) -> true end, evatar_test_time:guard()),
    S = joined_raw(Config, avatar, <<"mallory">>, ?AV_CRED),
    Desc = lamp_description(<<"mallory">>),
    [C | _] = maps:get(components, Desc),
    ok = gen_tcp:send(S, bil:encode_description(Desc#{components := [C#{id := Long}]})),
    {signal, #{context := error, body := #{type := <<"DescriptionRefused">>}}} = recv_doc(S),
    %% Long service names are refused the same way.
    #{consumes := [E]} = C,
    ok = gen_tcp:send(S, bil:encode_description(
                           Desc#{components := [C#{consumes := [E#{type := Long}]}]})),
    {signal, #{context := error, body := #{type := <<"DescriptionRefused">>}}} = recv_doc(S),
    ok = gen_tcp:send(S, bil:encode_description(Desc)),
    {control, {binding, _}} = recv_doc(S),
    Report = evatar_test_fixtures:wait_binding(
               Va, fun(#{entities := Es}) -> lists:member(<<"mallory">>, Es) end, 10000),
    Size = iolist_size(bil_control:encode({binding, Report})),
    ct:log("the VA's Binding report: ~b bytes", [Size]),
    true = Size < 4096,
    #{receiver := MyComp} = light_request(),
    Signal = #{id => Long, context => event, sender => <<"Light01">>, receiver => MyComp,
               in_reply_to => undefined, timestamp => 1, seq => undefined, epoch => undefined,
               body => #{category => <<"X">>, type => <<"Y">>, parameters => []}},
    ok = gen_tcp:send(S, bil:encode_signal(Signal)),
    {signal, #{context := error, in_reply_to := undefined,
               body := #{type := <<"IdTooLong">>}}} = recv_doc(S),
    ok = gen_tcp:close(S),
    ok = agent_bridge_client:close(Va).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

attached(Pairing, Entity) ->
    {ok, Registry} = evatar:registry(Pairing),
    [true] =:= [A || #{entity := E, attached := A} <- Registry, E =:= Entity].

%% The contents of the first Tag of each of the next Count frames on S that
%% have one, checking that each of those contains Must; S is in `{packet,
%% raw}' mode and its frames have 4-byte length headers. Frames without
%% Tag (control documents: Binding reports) are skipped. Each frame is
%% searched, not parsed (a reader that parses 100,000 frames falls behind).
ids(S, Tag, Must, Count) ->
    ids(S, {<<"<", Tag/binary, ">">>, <<"</", Tag/binary, ">">>, Must}, Count, <<>>, []).

ids(_S, _Tags, 0, _Buf, Acc) ->
    Acc;
ids(S, {Open, Close, Must} = Tags, Count, Buf, Acc) ->
    %% Any length the bridge may send (its frames here are a few KiB).
    case agent_bridge_frame:decode(Buf, 16#1000000) of
        {ok, Frame, Rest} ->
            case binary:match(Frame, Open) of
                {At, L} ->
                    From = At + L,
                    {To, _} = binary:match(Frame, Close,
                                           [{scope, {From, byte_size(Frame) - From}}]),
                    [exit({unexpected_frame, Frame}) || binary:match(Frame, Must) =:= nomatch],
                    ids(S, Tags, Count - 1, Rest, [binary:part(Frame, From, To - From) | Acc]);
                nomatch ->
                    ids(S, Tags, Count, Rest, Acc)
            end;
        {more, _} ->
            case gen_tcp:recv(S, 0, evatar_test_time:guard()) of
                {ok, More} -> ids(S, Tags, Count, <<Buf/binary, More/binary>>, Acc);
                {error, Why} -> exit({connection, Why, Count, length(Acc)})
            end
    end.

client(Config, Role, Entity, Cred) ->
    agent_bridge_client:connect([?config(addr, Config)],
                                #{pairing => ?config(pairing, Config), role => Role,
                                  entity_id => Entity, credential => Cred}).

hello(Config, Role, Entity, Cred, Version) ->
    evatar_test_fixtures:hello(?config(pairing, Config), Role, Entity, Cred, Version).

raw_connect(Config) ->
    {Ip, Port} = ?config(addr, Config),
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {packet, 4}, {active, false},
                                         {packet_size, 1048576}]),
    S.

joined_raw(Config, Role, Entity, Cred) ->
    S = raw_connect(Config),
    ok = gen_tcp:send(S, hello(Config, Role, Entity, Cred, 1)),
    {control, {welcome, _}} = recv_doc(S),
    S.

%% The Refused code a Hello gets; the connection is closed after it.
refused_code(Config, Hello) ->
    S = raw_connect(Config),
    ok = gen_tcp:send(S, Hello),
    {control, {refused, #{code := Code}}} = recv_doc(S),
    {error, closed} = gen_tcp:recv(S, 0, evatar_test_time:guard()),
    Code.

recv_doc(S) -> evatar_test_fixtures:recv_doc(S).

recv_until(S, Pred) -> evatar_test_fixtures:recv_until(S, Pred).

va_description(Id) ->
    evatar_test_fixtures:description(
      Id, agent, <<"TEST VA">>, <<>>,
      [evatar_test_fixtures:component(<<"LightEmulator01">>, [{<<"BEHAVIOUR">>, <<"Light">>}],
                                      [{<<"ACTUATOR">>, <<"TurnLightOn">>}])]).

lamp_description(Id) ->
    evatar_test_fixtures:description(
      Id, avatar, <<"LAMP">>, <<>>,
      [evatar_test_fixtures:component(<<"Light01">>, [{<<"ACTUATOR">>, <<"TurnLightOn">>}],
                                      [{<<"BEHAVIOUR">>, <<"Light">>}])]).

light_request() ->
    #{sender => <<"LightEmulator01">>, receiver => <<"Light01">>,
      body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>, parameters => []}}.

%% A pairing of its own with a VA and an Avatar that answers every request.
start_bystander(Addr) ->
    Pairing = <<"identity-bystander">>,
    {ok, _} = evatar_test_fixtures:create_pairing(Pairing, #{}),
    Config = [{addr, Addr}, {pairing, Pairing}],
    Parent = self(),
    Holder = spawn(fun() ->
                           {ok, Va} = client(Config, agent, <<"va">>,
                                             evatar_test_fixtures:va_credential()),
                           ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
                           Av = spawn(fun() ->
                                              {ok, C} = client(
                                                          Config, avatar, <<"av">>,
                                                          evatar_test_fixtures:avatar_credential()),
                                              ok = agent_bridge_client:describe(
                                                     C, lamp_description(<<"av">>)),
                                              answer(C)
                                      end),
                           _ = evatar_test_fixtures:wait_binding(
                                 Va, fun(#{bound := B}) -> B =/= [] end, 10000),
                           Parent ! {bystander, Va, Av},
                           receive stop -> ok end
                   end),
    receive {bystander, Va, Av} -> {Va, Av, Holder} after evatar_test_time:guard() -> ct:fail(no_bystander) end.

answer(Av) ->
    receive
        {agent_bridge, Av, {signal, #{context := request, id := Id, sender := From,
                                      receiver := To, body := Body}}} ->
            ok = agent_bridge_client:send(Av, #{context => feedback, sender => To,
                                                receiver => From, in_reply_to => Id,
                                                body => Body}),
            answer(Av);
        _ ->
            answer(Av)
    end.
