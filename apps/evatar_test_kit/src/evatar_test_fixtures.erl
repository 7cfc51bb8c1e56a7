%% @doc Test support: the fixtures the suites of several apps build alike
%% (apps/evatar_test_kit/README.md): the suites' pairing credentials and
%% pairings, BIL descriptions of the light-and-thermometer test bodies,
%% client options, raw protocol exchanges over a plain socket, an Avatar
%% that answers every request, TLS certificates made by
%% scripts/gen-bridge-certs.sh, and random secrets.
-module(evatar_test_fixtures).

-export([va_credential/0, avatar_credential/0, credential/1, create_pairing/2, wot_lamp_td/1,
         entry/2, component/3, description/5, va_description/1, avatar_description/1,
         client_opts/3, client/4,
         hello/5, raw_connect/1, recv_doc/1, recv_doc/2, recv_until/2, recv_until/3,
         refused_code/2,
         start_responder/3, responder/1, wait_binding/3, wait_signal/3,
         bridge_certs/2, repo_root/0, secret/0, secret_atom/0]).

-type addr() :: {inet:ip_address(), inet:port_number()}.
-export_type([addr/0]).

-define(RECV_TIMEOUT, 10000).

%% ---------------------------------------------------------------------------
%% Pairings
%% ---------------------------------------------------------------------------

%% @doc The credential of the VAs of the suites' pairings.
-spec va_credential() -> binary().
va_credential() -> <<"va-secret">>.

%% @doc The credential of the Avatars of the suites' pairings.
-spec avatar_credential() -> binary().
avatar_credential() -> <<"avatar-secret">>.

%% @doc A Thing Description of a lamp named Title whose TD the suites read
%% from a file (wot_avatar's `{file, Path}'): an action on 127.0.0.1 port 9,
%% where nothing answers (the Avatar joins; a request would fail), and one
%% with a CoAP form, which the Avatar leaves out (its one problem,
%% `unsupported_scheme'). Allow host 127.0.0.1.
-spec wot_lamp_td(binary()) -> binary().
wot_lamp_td(Title) ->
    <<"{\"@context\": \"https://www.w3.org/2022/wot/td/v1.1\", \"title\": \"", Title/binary, "\",\n"
      " \"securityDefinitions\": {\"nosec_sc\": {\"scheme\": \"nosec\"}}, \"security\": \"nosec_sc\",\n"
      " \"actions\": {\"toggle\": {\"forms\": [{\"href\": \"http://127.0.0.1:9/toggle\"}]},\n"
      "             \"blink\": {\"forms\": [{\"href\": \"coap://127.0.0.1/blink\"}]}}}\n">>.

%% @doc The credential for a role of the suites' pairings.
-spec credential(agent | avatar) -> binary().
credential(agent) -> va_credential();
credential(avatar) -> avatar_credential().

%% @doc A pairing with the suites' credentials and the options Opts.
-spec create_pairing(binary(), map()) -> {ok, pid()}.
create_pairing(Id, Opts) ->
    {ok, _} = evatar:create_pairing(Id, Opts#{agent_credential => va_credential(),
                                              avatar_credential => avatar_credential()}).

%% ---------------------------------------------------------------------------
%% Descriptions
%% ---------------------------------------------------------------------------

%% @doc A service or consumption entry without parameters.
-spec entry(binary(), binary()) -> map().
entry(Cat, Type) -> #{category => Cat, type => Type, parameters => []}.

%% @doc A component providing Services and consuming Consumes, each a list
%% of `{Category, Type}'.
-spec component(binary(), [{binary(), binary()}], [{binary(), binary()}]) -> map().
component(Id, Services, Consumes) ->
    #{id => Id, services => [entry(C, T) || {C, T} <- Services],
      consumes => [entry(C, T) || {C, T} <- Consumes]}.

%% @doc A description of entity Id of type agent or avatar.
-spec description(binary(), agent | avatar, binary(), binary(), [map()]) -> bil:description().
description(Id, Type, ApiName, Context, Components) ->
    #{entity_id => Id, api_name => ApiName, entity_type => Type, context => Context,
      components => Components}.

%% @doc The suites' VA body: a light emulator consuming TurnLightOn, and a
%% thermometer emulator providing the Temperature the Avatar's sensor
%% streams.
-spec va_description(binary()) -> bil:description().
va_description(Id) ->
    description(Id, agent, <<"TEST VA">>, <<"EmulatorDescription">>,
                [component(<<"LightEmulator01">>, [{<<"BEHAVIOUR">>, <<"Light">>}],
                           [{<<"ACTUATOR">>, <<"TurnLightOn">>}]),
                 component(<<"ThermoEmulator01">>, [{<<"SENSOR">>, <<"Temperature">>}], [])]).

%% @doc The suites' Avatar body: a light providing TurnLightOn, and a
%% thermometer consuming the VA's Temperature.
-spec avatar_description(binary()) -> bil:description().
avatar_description(Id) ->
    description(Id, avatar, <<"TEST AVATAR">>, <<"ActuatorDescription">>,
                [component(<<"Light01">>, [{<<"ACTUATOR">>, <<"TurnLightOn">>}], []),
                 component(<<"Thermo01">>, [{<<"SENSOR">>, <<"Reading">>}],
                           [{<<"SENSOR">>, <<"Temperature">>}])]).

%% ---------------------------------------------------------------------------
%% Clients
%% ---------------------------------------------------------------------------

%% @doc agent_bridge_client options for entity Entity of Role in Pairing,
%% with the suites' credential for the role.
-spec client_opts(binary(), agent | avatar, binary()) -> map().
client_opts(Pairing, Role, Entity) ->
    #{pairing => Pairing, role => Role, entity_id => Entity, credential => credential(Role)}.

%% @doc A client of Pairing at Addr, with the options of client_opts/3.
-spec client(addr(), binary(), agent | avatar, binary()) -> {ok, pid()} | {error, term()}.
client(Addr, Pairing, Role, Entity) ->
    agent_bridge_client:connect([Addr], client_opts(Pairing, Role, Entity)).

%% @doc The first Binding report to client C that satisfies Pred, within
%% Timeout ms of each report; the case fails without one.
-spec wait_binding(pid(), fun((map()) -> boolean()), timeout()) -> map().
wait_binding(C, Pred, Timeout) ->
    wait_report(C, binding, Pred, Timeout, no_binding).

%% @doc The first signal to client C that satisfies Pred, within Timeout ms
%% of each signal; the case fails without one.
-spec wait_signal(pid(), fun((map()) -> boolean()), timeout()) -> map().
wait_signal(C, Pred, Timeout) ->
    wait_report(C, signal, Pred, Timeout, no_signal).

wait_report(C, Kind, Pred, Timeout, Failure) ->
    receive
        {agent_bridge, C, {Kind, Report}} ->
            case Pred(Report) of
                true -> Report;
                false -> wait_report(C, Kind, Pred, Timeout, Failure)
            end
    after Timeout -> exit({test_case_failed, Failure})
    end.

%% @doc An Avatar client (Connect() starts it) in a process of its own,
%% described by Description, that answers every request with its feedback;
%% returns that process once the description is sent. Sensor(I) makes the
%% I-th reading it sends when asked (responder/1).
-spec start_responder(fun(() -> {ok, pid()}), bil:description(),
                      fun((pos_integer()) -> map())) -> pid().
start_responder(Connect, Description, Sensor) ->
    Self = self(),
    Pid = spawn(fun() ->
                        {ok, C} = Connect(),
                        ok = agent_bridge_client:describe(C, Description),
                        Self ! {responder, self()},
                        responder(#{client => C, answer => true, sensor => Sensor})
                end),
    receive {responder, Pid} -> Pid
    after ?RECV_TIMEOUT -> exit({test_case_failed, responder_not_started})
    end.

%% @doc The loop of start_responder/3: answers requests with a feedback
%% echoing the request's body without parameters while `answer' holds;
%% `mute' stops the answers, `{leave_unanswered, Id, From}' leaves the
%% request with SignalID Id unanswered (told to From once in force, so
%% that a request sent after cannot overtake it), `{stream, N}' sends N
%% sensor signals; ends when its client is closed.
-spec responder(#{client := pid(), answer := boolean(), sensor := fun(),
                  unanswered => [binary()]}) -> ok.
responder(#{client := C, answer := Answer, sensor := Sensor} = St) ->
    Unanswered = maps:get(unanswered, St, []),
    receive
        {agent_bridge, C, {signal, #{context := request, id := Id, sender := From,
                                     receiver := To, body := Body}}} when Answer ->
            case lists:member(Id, Unanswered) of
                true -> ok;
                false ->
                    ok = agent_bridge_client:send(C, #{context => feedback, sender => To,
                                                       receiver => From, in_reply_to => Id,
                                                       body => Body#{parameters => []}})
            end,
            responder(St);
        {leave_unanswered, Id, From} ->
            From ! {leaving_unanswered, self(), Id},
            responder(St#{unanswered => [Id | Unanswered]});
        mute ->
            responder(St#{answer := false});
        {stream, N} ->
            _ = [ok = agent_bridge_client:send(C, Sensor(I)) || I <- lists:seq(1, N)],
            responder(St);
        {agent_bridge, C, {closed, _}} ->
            ok;
        _ ->
            responder(St)
    end.

%% ---------------------------------------------------------------------------
%% The protocol over a plain socket
%% ---------------------------------------------------------------------------

%% @doc A Hello frame's document.
-spec hello(binary(), agent | avatar | binary(), binary(), binary(), pos_integer()) -> iodata().
hello(Pairing, Role, Entity, Cred, Version) ->
    bil_control:encode({hello, #{pairing => Pairing, role => Role, entity_id => Entity,
                                 credential => Cred, protocol_version => Version}}).

%% @doc A plain TCP connection to a bridge listener, 4-byte frames, passive.
-spec raw_connect(addr()) -> gen_tcp:socket().
raw_connect({Ip, Port}) ->
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {packet, 4}, {active, false}]),
    S.

%% @doc The next document on S, parsed; fails the case after 10 s.
-spec recv_doc(gen_tcp:socket()) -> term().
recv_doc(S) ->
    recv_doc(S, ?RECV_TIMEOUT).

%% @doc The next document on S within Timeout ms, parsed.
-spec recv_doc(gen_tcp:socket(), timeout()) -> term().
recv_doc(S, Timeout) ->
    {ok, Frame} = gen_tcp:recv(S, 0, Timeout),
    {ok, Doc} = bil_control:parse_frame(Frame, #{}),
    Doc.

%% @doc The first document on S that satisfies Pred; earlier ones are
%% dropped.
-spec recv_until(gen_tcp:socket(), fun((term()) -> boolean())) -> term().
recv_until(S, Pred) ->
    recv_until(S, Pred, ?RECV_TIMEOUT).

%% @doc recv_until/2, waiting at most Timeout ms for each document.
-spec recv_until(gen_tcp:socket(), fun((term()) -> boolean()), timeout()) -> term().
recv_until(S, Pred, Timeout) ->
    Doc = recv_doc(S, Timeout),
    case Pred(Doc) of
        true -> Doc;
        false -> recv_until(S, Pred, Timeout)
    end.

%% @doc The Refused code the listener at Addr answers Hello with; checks
%% that the connection is closed after it.
-spec refused_code(addr(), iodata()) -> binary() | atom().
refused_code(Addr, Hello) ->
    S = raw_connect(Addr),
    ok = gen_tcp:send(S, Hello),
    {control, {refused, #{code := Code}}} = recv_doc(S),
    {error, closed} = gen_tcp:recv(S, 0, ?RECV_TIMEOUT),
    Code.

%% ---------------------------------------------------------------------------
%% Certificates and secrets
%% ---------------------------------------------------------------------------

%% @doc Runs scripts/gen-bridge-certs.sh: a CA, a server certificate for
%% localhost and 127.0.0.1, and a client certificate per name, in Dir.
-spec bridge_certs(file:filename(), [string()]) -> file:filename().
bridge_certs(Dir, Clients) ->
    Script = filename:join([repo_root(), "scripts", "gen-bridge-certs.sh"]),
    Out = os:cmd(lists:join(" ", ["EVATAR_SERVER_HOSTS='localhost 127.0.0.1'", "bash", Script, Dir
                                  | Clients]) ++ " 2>&1; echo rc=$?"),
    case string:find(Out, "rc=0\n") of
        nomatch -> exit({test_case_failed, {gen_bridge_certs, Out}});
        _ -> Dir
    end.

%% @doc The root of the source tree (where scripts/ is), found from where
%% the evatar application was compiled.
-spec repo_root() -> file:filename().
repo_root() ->
    Src = proplists:get_value(source, evatar:module_info(compile)),
    filename:dirname(filename:dirname(filename:dirname(filename:dirname(Src)))).

%% @doc 48 random hex digits: a secret no one outside the run can guess.
-spec secret() -> string().
secret() ->
    lists:flatten([io_lib:format("~2.16.0b", [B]) || <<B>> <= crypto:strong_rand_bytes(24)]).

%% @doc secret/0 as an atom (a distribution cookie). Made on demand: a test
%% makes a handful, never from input.
-spec secret_atom() -> atom().
secret_atom() ->
    list_to_atom(secret()).
