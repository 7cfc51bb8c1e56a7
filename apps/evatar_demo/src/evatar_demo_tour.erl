%% @doc Internal. The tour of BIL and EVATAR over TCP (`make demo
%% DEMO_ARGS=bil'; evatar_demo dispatches to it).
%%
%% Part one shows BIL at work on the shipped examples: every description and
%% signal parsed, encoded and parsed back, the bodies of a LEGO robot and a
%% smart home bound to their VAs (the Body Mapping Registry printed), and
%% hostile documents refused with the error a sender would receive. Part two
%% runs EVATAR itself: a pairing, a VA and a LEGO robot Avatar joining over
%% TCP with agent_bridge_client, binding, requests with their round-trip
%% times, a sensor stream, a feedback timeout, a NotBound refusal, a new
%% description, and the operator's view of it all.
-module(evatar_demo_tour).

-export([main/0]).

%% @doc Runs the tour, printing as it goes.
-spec main() -> ok.
main() ->
    evatar_demo:quietly(fun run/0).

run() ->
    {ok, _} = application:ensure_all_started(bil),
    say("EVATAR demo on node ~s (OTP ~s)", [node(), erlang:system_info(otp_release)]),
    Dir = examples_dir(),
    section("1. BIL descriptions and signals from ~s", [Dir]),
    Docs = [load(Dir, F) || F <- lists:sort(filelib:wildcard("*.xml", Dir))],
    section("2. Binding: the Body Mapping Registry of each VA-Avatar pairing", []),
    bind_pair(<<"LEGO robot">>, Docs, "lego_va.xml", "lego_robot.xml"),
    bind_pair(<<"smart home">>, Docs, "smart_home_va.xml", "smart_home.xml"),
    section("3. Untrusted input is refused with a reason the sender can act on", []),
    lists:foreach(fun hostile/1, hostile_documents()),
    ok = live(Docs),
    say("", []),
    say("Done. `make test` runs every check; docs/bil.md is the language reference and "
        "docs/protocol.md the wire protocol.", []),
    ok.

%% Each example is parsed, encoded and parsed again; the two terms must agree.
load(Dir, File) ->
    {ok, Bin} = file:read_file(filename:join(Dir, File)),
    {Kind, Parse, Encode} = kind(File),
    {ok, Term} = Parse(Bin),
    Encoded = iolist_to_binary(Encode(Term)),
    RoundTrip = case Parse(Encoded) of
                    {ok, Term} -> "round trip ok";
                    Other -> io_lib:format("ROUND TRIP DIFFERS: ~p", [Other])
                end,
    say("  ~-32s ~-11s ~6b bytes in, ~6b out, ~s; ~s",
        [File, Kind, byte_size(Bin), byte_size(Encoded), RoundTrip, summary(Kind, Term)]),
    {File, Term}.

kind("signal_" ++ _) ->
    {signal, fun bil:parse_signal/1, fun bil:encode_signal/1};
kind(_) ->
    {description, fun bil:parse_description/1, fun bil:encode_description/1}.

summary(description, #{entity_id := Id, entity_type := Type, components := Cs}) ->
    Services = lists:sum([length(S) || #{services := S} <- Cs]),
    Consumes = lists:sum([length(C) || #{consumes := C} <- Cs]),
    io_lib:format("~s ~s: ~b components, ~b services, ~b consumes",
                  [Type, Id, length(Cs), Services, Consumes]);
summary(signal, #{context := Ctx, sender := From, receiver := To,
                  body := #{category := Cat, type := Type}}) ->
    io_lib:format("~s ~s -> ~s: ~s/~s", [Ctx, From, To, Cat, Type]).

bind_pair(Name, Docs, VaFile, AvatarFile) ->
    case {lists:keyfind(VaFile, 1, Docs), lists:keyfind(AvatarFile, 1, Docs)} of
        {{_, Va}, {_, Avatar}} ->
            {Micros, #{bound := Bound, unbound := Unbound}} =
                timer:tc(bil, bind, [[Va, Avatar]]),
            say("", []),
            say("  ~s: ~b bound, ~b unbound (computed in ~b us)",
                [Name, length(Bound), length(Unbound), Micros]),
            say("    ~-36s ~-36s ~s", ["consumer", "provider", "service"]),
            [say("    ~-36s ~-36s ~s/~s (~b candidate(s))",
                 [endpoint(C), endpoint(P), Cat, Type, N])
             || #{consumer := C, provider := P, category := Cat, type := Type,
                  candidates := N} <- Bound],
            [say("    ~-36s ~-36s ~s/~s", [endpoint(C), ["unbound: ", atom_to_list(R)], Cat, Type])
             || #{consumer := C, category := Cat, type := Type, reason := R} <- Unbound],
            ok;
        _ ->
            say("  ~s: examples ~s and ~s not found", [Name, VaFile, AvatarFile])
    end.

endpoint(#{entity := E, component := C}) -> [E, "/", C].

hostile_documents() ->
    Laughs = <<"<?xml version=\"1.0\"?>\n<!DOCTYPE lolz [\n"
               "  <!ENTITY lol \"lol\">\n"
               "  <!ENTITY lol2 \"&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;\">\n"
               "]>\n<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\">&lol2;</bil:Envelope>">>,
    Deep = iolist_to_binary([lists:duplicate(20000, "<a>")]),
    Big = iolist_to_binary([<<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\">">>,
                            binary:copy(<<" ">>, 70000)]),
    Truncated = <<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\"><bil:Header><SignalID>1</Sig">>,
    NoService = <<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\"><bil:Header><SignalID>1</SignalID>"
                  "<Context>Teleport</Context></bil:Header></bil:Envelope>">>,
    [{"billion laughs", Laughs}, {"20,000 nested elements", Deep},
     {"70 KB signal", Big}, {"truncated signal", Truncated},
     {"unknown context", NoService}, {"binary garbage", rand:bytes(64)}].

hostile({Name, Bin}) ->
    {Micros, Result} = timer:tc(bil, parse_signal, [Bin]),
    case Result of
        {error, Reason} ->
            say("  ~-24s refused in ~b us: ~s", [Name, Micros, bil:format_error(Reason)]);
        {ok, _} ->
            say("  ~-24s ACCEPTED (unexpected)", [Name])
    end.

%% ---------------------------------------------------------------------------
%% Part two: EVATAR over TCP
%% ---------------------------------------------------------------------------

-define(PAIRING, <<"demo-lego">>).
-define(LISTENER, evatar_demo_tour).
-define(VA_CRED, <<"demo-va-secret">>).
-define(AV_CRED, <<"demo-avatar-secret">>).
%% Short, so that the timeout step does not keep the reader waiting.
-define(FEEDBACK_TIMEOUT, 400).

live(Docs) ->
    {_, Va0} = lists:keyfind("lego_va.xml", 1, Docs),
    {_, Robot} = lists:keyfind("lego_robot.xml", 1, Docs),
    section("4. EVATAR live: a VA and its LEGO robot join a pairing over TCP", []),
    {Started, RestoreEnv} = start_apps(),
    {ok, _} = agent_bridge:start_listener(?LISTENER, #{ip => {127, 0, 0, 1}, port => 0}),
    {ok, {Ip, Port} = Endpoint} = agent_bridge:address(?LISTENER),
    say("  listener on ~s:~b (agent_bridge), applications started: ~w",
        [inet:ntoa(Ip), Port, Started]),
    {ok, _} = evatar:create_pairing(?PAIRING, #{agent_credential => ?VA_CRED,
                                                avatar_credential => ?AV_CRED,
                                                join_timeout => 5000,
                                                feedback_timeout => ?FEEDBACK_TIMEOUT}),
    say("  pairing ~s created (feedback timeout ~b ms)", [?PAIRING, ?FEEDBACK_TIMEOUT]),
    try
        run_pairing(Endpoint, Va0, Robot)
    after
        _ = evatar:delete_pairing(?PAIRING),
        ok = agent_bridge:stop_listener(?LISTENER),
        lists:foreach(fun application:stop/1, lists:reverse(Started)),
        RestoreEnv()
    end,
    say("  pairing deleted, listener stopped, applications stopped", []).

%% Starts what is not running yet, without the default listener on port
%% 7400: the demo uses its own on a free port.
start_apps() ->
    case lists:keymember(agent_bridge, 1, application:which_applications()) of
        true ->
            {[], fun() -> ok end};
        false ->
            _ = application:load(agent_bridge),
            Saved = application:get_env(agent_bridge, listeners),
            ok = application:set_env(agent_bridge, listeners, []),
            {ok, Started} = application:ensure_all_started(agent_bridge),
            {Started, fun() -> restore_env(agent_bridge, listeners, Saved) end}
    end.

restore_env(App, Key, undefined) -> application:unset_env(App, Key);
restore_env(App, Key, {ok, Value}) -> application:set_env(App, Key, Value).

run_pairing(Endpoint, VaFull, Robot) ->
    %% The VA's first virtual body has no bumper emulator (its description
    %% without TouchSensorEmulator); it adds one later.
    Va0 = VaFull#{components := [C || #{id := Id} = C <- maps:get(components, VaFull),
                                      Id =/= <<"TouchSensorEmulator">>]},
    #{entity_id := VaId} = VaFull,
    #{entity_id := RobotId} = Robot,
    section("  4.1 Joining: Hello, then Welcome", []),
    {ok, Va} = join(Endpoint, agent, VaId, ?VA_CRED, self()),
    Avatar = spawn_link(fun avatar/0),
    {ok, Av} = join(Endpoint, avatar, RobotId, ?AV_CRED, Avatar),
    Avatar ! {client, Av},
    section("  4.2 Describing and binding", []),
    ok = agent_bridge_client:describe(Va, Va0),
    say("  VA ~s described itself: ~b components, no bumper emulator", [VaId, count(Va0)]),
    First = await_binding(Va, 1),
    say("  binding report to the VA: ~b bound, ~b unbound (its body is not there yet)",
        [length(maps:get(bound, First)), length(maps:get(unbound, First))]),
    ok = agent_bridge_client:describe(Av, Robot),
    say("  Avatar ~s described itself: ~b components", [RobotId, count(Robot)]),
    narrate_binding(await_binding(Va, 2)),
    section("  4.3 Signals through the Body Mapping Registry", []),
    ok = rotate_request(Va),
    ok = forward_request(Va),
    ok = sensor_stream(Va, Avatar, 5),
    ok = feedback_timeout(Va),
    ok = not_bound(Va),
    section("  4.4 A new description: the VA adds its bumper emulator", []),
    ok = agent_bridge_client:describe(Va, VaFull),
    #{bound := Bound, unbound := Unbound} = await_binding(Va, 2),
    say("  rebound at once: ~b bound, ~b unbound; TouchSensor -> TouchSensorEmulator is bound",
        [length(Bound), length(Unbound)]),
    section("  4.5 What an operator sees from a remote shell (erl -remsh)", []),
    say("  > evatar:print_pairings().", []),
    ok = evatar:print_pairings(),
    say("~n  > evatar:print_bindings(<<\"~s\">>).", [?PAIRING]),
    ok = evatar:print_bindings(?PAIRING),
    say("~n  > evatar:print_stats(<<\"~s\">>).", [?PAIRING]),
    ok = evatar:print_stats(?PAIRING),
    section("  4.6 Leaving", []),
    ok = agent_bridge_client:close(Va),
    ok = stop_avatar(Avatar),
    say("  VA and Avatar said Bye and closed their connections", []).

join(Endpoint, Role, EntityId, Credential, Owner) ->
    Opts = #{pairing => ?PAIRING, role => Role, entity_id => EntityId,
             credential => Credential, owner => Owner},
    {ok, Client} = agent_bridge_client:connect([Endpoint], Opts),
    {ok, #{session_id := Sid, join_timeout := JoinTimeout}} =
        agent_bridge_client:session(Client),
    say("  ~-6s ~s joined: session ~s, must describe itself within ~b ms",
        [Role, EntityId, binary:part(Sid, 0, 8), JoinTimeout]),
    {ok, Client}.

count(#{components := Cs}) -> length(Cs).

%% The next Binding report naming at least N registered entities.
await_binding(Va, N) ->
    receive
        {agent_bridge, Va, {binding, #{entities := Entities} = Report}}
          when length(Entities) >= N ->
            Report;
        {agent_bridge, Va, {binding, _}} ->
            await_binding(Va, N)
    after 5000 ->
            error({no_binding_report, N})
    end.

narrate_binding(#{bound := Bound, unbound := Unbound}) ->
    say("  bound: ~b consumer/provider pairs, for example", [length(Bound)]),
    [say("    ~-36s -> ~-36s ~s/~s", [endpoint(C), endpoint(P), Cat, Type])
     || #{consumer := C, provider := P, category := Cat, type := Type} <- Bound,
        is_example(C)],
    say("  unbound: ~b", [length(Unbound)]),
    [say("    ~-36s    ~-36s ~s/~s: ~s", [endpoint(C), "", Cat, Type, reason(R)])
     || #{consumer := C, category := Cat, type := Type, reason := R} <- Unbound],
    ok.

is_example(#{component := C}) ->
    lists:member(C, [<<"MotorAEmulator">>, <<"MotorBEmulator">>, <<"LightSensor">>]).

reason(no_provider) -> "no provider (the VA has no bumper emulator)";
reason(parameters_mismatch) -> "parameters mismatch".

%% A fine-grain request: the Avatar answers at once.
rotate_request(Va) ->
    Request = signal(<<"MotorAEmulator">>, <<"MotorA">>, <<"ACTUATOR">>, <<"Rotate">>,
                     [{<<"Port">>, <<"A">>}, {<<"Angle">>, <<"360">>},
                      {<<"Speed">>, <<"180">>}]),
    say("  request  MotorAEmulator -> MotorA: ACTUATOR/Rotate Angle=360 Speed=180", []),
    {Micros, {ok, Feedback}} = timer:tc(agent_bridge_client, request, [Va, Request, 5000]),
    say("  feedback ~s -> ~s: ~s (seq ~b), round trip ~s",
        [maps:get(sender, Feedback), maps:get(receiver, Feedback), body(Feedback),
         maps:get(seq, Feedback), ms(Micros)]),
    ok.

%% A coarse-grain request: progress first, then the final feedback.
forward_request(Va) ->
    Request = signal(<<"ForwardBehaviourEmulator">>, <<"ForwardBehaviour">>, <<"BEHAVIOUR">>,
                     <<"Forward">>, [{<<"Distance">>, <<"10">>}, {<<"Speed">>, <<"0.2">>}]),
    say("  request  ForwardBehaviourEmulator -> ForwardBehaviour: BEHAVIOUR/Forward "
        "Distance=10 (walk 10 m)", []),
    {Micros, {ok, Feedback}} = timer:tc(agent_bridge_client, request, [Va, Request, 5000]),
    [say("  progress ~s -> ~s: ~s", [From, To, body(P)])
     || {agent_bridge, _, {signal, #{context := progress, sender := From, receiver := To} = P}}
            <- drain(Va)],
    say("  feedback ~s -> ~s: ~s, round trip ~s",
        [maps:get(sender, Feedback), maps:get(receiver, Feedback), body(Feedback), ms(Micros)]),
    ok.

sensor_stream(Va, Avatar, N) ->
    say("  stream   LightSensor -> LightSensorEmulator: ~b SensorData SENSOR/Luminosity", [N]),
    Avatar ! {stream, N},
    lists:foreach(
      fun(_) ->
              receive
                  {agent_bridge, Va, {signal, #{context := sensor_data, seq := Seq} = S}} ->
                      say("    at the VA: Sequence ~-4b ~s", [Seq, body(S)])
              after 5000 -> error(no_sensor_data)
              end
      end, lists:seq(1, N)).

%% The Avatar ignores Grab requests: EVATAR answers in its place.
feedback_timeout(Va) ->
    Request = signal(<<"GrabBehaviourEmulator">>, <<"GrabBehaviour">>, <<"BEHAVIOUR">>,
                     <<"Grab">>, []),
    say("  request  GrabBehaviourEmulator -> GrabBehaviour: BEHAVIOUR/Grab "
        "(the Avatar stays silent)", []),
    {Micros, {ok, #{sender := From} = Feedback}} =
        timer:tc(agent_bridge_client, request, [Va, Request, 5000]),
    say("  feedback ~s -> GrabBehaviourEmulator after ~s: ~s", [From, ms(Micros), body(Feedback)]),
    ok.

%% MotorB exists but is bound to MotorBEmulator, not to MotorAEmulator.
not_bound(Va) ->
    Request = signal(<<"MotorAEmulator">>, <<"MotorB">>, <<"ACTUATOR">>, <<"Rotate">>,
                     [{<<"Port">>, <<"B">>}, {<<"Angle">>, <<"90">>}]),
    say("  request  MotorAEmulator -> MotorB (outside MotorAEmulator's bindings)", []),
    {error, Error} = agent_bridge_client:request(Va, Request, 5000),
    say("  error    ~s -> ~s: ~s; MotorB never saw it", [maps:get(sender, Error),
                                                        maps:get(receiver, Error), body(Error)]),
    ok.

signal(Sender, Receiver, Category, Type, Parameters) ->
    #{sender => Sender, receiver => Receiver,
      body => #{category => Category, type => Type, parameters => Parameters}}.

body(#{body := #{category := Cat, type := Type, parameters := Ps}}) ->
    [Cat, "/", Type, [[" ", N, "=", V] || {N, V} <- Ps]].

ms(Micros) -> io_lib:format("~.2f ms", [Micros / 1000]).

drain(Client) ->
    receive
        {agent_bridge, Client, _} = Message -> [Message | drain(Client)]
    after 0 -> []
    end.

%% The LEGO robot: answers requests with feedback (Forward with a progress
%% first), ignores Grab, streams light readings when told.
avatar() ->
    receive {client, Client} -> avatar(Client) end.

avatar(Client) ->
    receive
        {agent_bridge, Client, {signal, #{context := request, receiver := <<"GrabBehaviour">>}}} ->
            avatar(Client);
        {agent_bridge, Client, {signal, #{context := request} = Request}} ->
            ok = answer(Client, Request),
            avatar(Client);
        {agent_bridge, Client, _} ->
            avatar(Client);
        {stream, N} ->
            lists:foreach(
              fun(I) ->
                      ok = agent_bridge_client:send(
                             Client, (signal(<<"LightSensor">>, <<"LightSensorEmulator">>,
                                             <<"SENSOR">>, <<"Luminosity">>,
                                             [{<<"Unit">>, <<"percent">>},
                                              {<<"Value">>, integer_to_binary(40 + 3 * I)}]))
                                     #{context => sensor_data})
              end, lists:seq(1, N)),
            avatar(Client);
        {stop, From} ->
            ok = agent_bridge_client:close(Client),
            From ! {stopped, self()}
    end.

answer(Client, #{id := Id, sender := Sender, receiver := Me,
                 body := #{category := Cat, type := Type}}) ->
    Reply = fun(Context, Parameters) ->
                    (signal(Me, Sender, Cat, <<"ACTION FEEDBACK">>, Parameters))
                        #{context => Context, in_reply_to => Id}
            end,
    case Type of
        <<"Forward">> ->
            ok = agent_bridge_client:send(Client, Reply(progress, [{<<"Done">>, <<"50%">>}]));
        _ ->
            ok
    end,
    agent_bridge_client:send(Client, Reply(feedback, [{<<"Done">>, <<"yes">>}])).

stop_avatar(Avatar) ->
    Avatar ! {stop, self()},
    receive {stopped, Avatar} -> ok
    after 5000 -> error(avatar_did_not_stop)
    end.

examples_dir() ->
    filename:join(code:priv_dir(bil), "examples").

section(Fmt, Args) ->
    say("", []),
    say(Fmt, Args).

say(Fmt, Args) ->
    io:format(Fmt ++ "~n", Args).
