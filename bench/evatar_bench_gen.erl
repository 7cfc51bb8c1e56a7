%% @doc Internal to the mediator benchmark (evatar_bench). The load
%% generator: one VA process and one Avatar process per pairing, joined over
%% loopback TCP either with agent_bridge_client (`client' mode) or with a
%% minimal raw-socket client that sends pre-encoded frames and finds ids by
%% binary matching (`raw' mode, so the generator's own CPU stays small).
-module(evatar_bench_gen).

-export([setup/3, setup/4, new_counters/2, count/1, request_body/0, feedback_body/0,
         descriptions/2, credentials/0, idle_join/4, answer_kind/1]).
-export([va_init/6, avatar_init/5, sink/0, start_reading/2, read_on/2, reactivate/2]).
-export([flood_va_init/6, silent_avatar_init/4]).

-export_type([mode/0, pair/0, flood_kind/0]).

%% `floor' is the raw generator against evatar_bench_floor's relays, which
%% forward frames untouched: the same sockets and process hops as EVATAR
%% with none of its work. `direct' joins through the evatar API from plain
%% processes: the pairing's own cost, without TCP, XML or the bridge.
%% (`codec' is `floor' with relays that parse and encode; the controller's
%% `split' is `raw' with these processes on another node, see setup/4.)
-type mode() :: client | raw | direct | evatar_bench_floor:kind().
%% One pairing of the benchmark: its id, the VA process (which the
%% controller drives) and the Avatar process.
-type pair() :: #{id := binary(), index := pos_integer(), va := pid(), avatar := pid(),
                  relays => [pid()]}.
-type address() :: {inet:ip_address(), inet:port_number()}.

-define(VA_COMPONENT, <<"LightEmulator01">>).
-define(AV_COMPONENT, <<"HomeLightActuator01">>).
-define(AGENT_CRED, <<"bench-agent-credential">>).
-define(AVATAR_CRED, <<"bench-avatar-credential">>).
-define(SETUP_TIMEOUT, 60000).
-define(ACTIVE_N, 32).

%% ---------------------------------------------------------------------------
%% Documents
%% ---------------------------------------------------------------------------

%% @doc The agent and avatar credentials every benchmark pairing uses.
-spec credentials() -> #{agent_credential := binary(), avatar_credential := binary()}.
credentials() -> #{agent_credential => ?AGENT_CRED, avatar_credential => ?AVATAR_CRED}.

%% @doc The VA's and the Avatar's descriptions in pairing I (the light
%% actuator of docs/bil.md, section 4.1).
-spec descriptions(pos_integer(), binary()) -> {bil:description(), bil:description()}.
descriptions(I, Tag) ->
    {VaId, AvId} = entity_ids(I, Tag),
    Va = #{entity_id => VaId, api_name => <<"LIGHT VA">>, entity_type => agent,
           context => <<"EmulatorDescription">>,
           components =>
               [#{id => ?VA_COMPONENT,
                  services => [#{category => <<"ACTUATOR">>, type => <<"ActionFeedback">>,
                                 parameters => [{<<"Feedback">>, <<"yes">>}]}],
                  consumes => [#{category => <<"actuator">>, type => <<"TurnLightOn">>,
                                 parameters => [{<<"Light">>, <<"yes">>},
                                                {<<"Email">>, <<"no">>}]}]}]},
    Av = #{entity_id => AvId, api_name => <<"LIGHT ACTUATOR">>, entity_type => avatar,
           context => <<"ActuatorDescription">>,
           components =>
               [#{id => ?AV_COMPONENT,
                  services => [#{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                                 parameters => [{<<"Light">>, <<"yes">>},
                                                {<<"Email">>, <<"no">>}]}],
                  consumes => [#{category => <<"ACTUATOR">>, type => <<"ACTION FEEDBACK">>,
                                 parameters => [{<<"Feedback">>, <<"yes">>}]}]}]},
    {Va, Av}.

entity_ids(I, Tag) ->
    N = integer_to_binary(I),
    {<<"va-", Tag/binary, "-", N/binary>>, <<"av-", Tag/binary, "-", N/binary>>}.

%% @doc The request's body: with the header, about 530 bytes on the wire.
-spec request_body() -> bil:entry().
request_body() ->
    #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
      parameters => [{<<"Light">>, <<"yes">>}, {<<"Brightness">>, <<"80">>},
                     {<<"Colour">>, <<"warm-white-2700K">>}, {<<"Room">>, <<"living-room">>}]}.

%% @doc The feedback's body: with the header, about 500 bytes on the wire.
-spec feedback_body() -> bil:entry().
feedback_body() ->
    #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
      parameters => [{<<"Done">>, <<"yes">>}, {<<"Light">>, <<"on">>},
                     {<<"Duration">>, <<"12">>}]}.

%% ---------------------------------------------------------------------------
%% Setting up loaded pairings
%% ---------------------------------------------------------------------------

%% @doc Creates pairings 1..N, and for each starts an Avatar and a VA
%% process that join over TCP and wait until bound. At most 32 pairings are
%% set up at a time. Crashes the benchmark on any failure: figures from a
%% half-built system would mislead. For `floor', Addr is the floor's
%% address and listening socket.
-spec setup(pos_integer(), mode(), address() | {address(), gen_tcp:socket()}) -> [pair()].
setup(N, Mode, Addr) ->
    setup(N, Mode, Addr, node()).

%% @doc The same, with the VA and Avatar processes on node Node (another
%% OS process), so that this node's CPU is EVATAR's alone.
-spec setup(pos_integer(), mode(), address() | {address(), gen_tcp:socket()}, node()) ->
          [pair()].
setup(N, Mode, Addr, Node) ->
    setup_batches(lists:seq(1, N), Mode, Addr, Node, []).

setup_batches([], _Mode, _Addr, _Node, Acc) ->
    lists:reverse(Acc);
setup_batches(Is, Mode, Addr, Node, Acc) ->
    {Batch, Rest} = lists:split(min(32, length(Is)), Is),
    Pairs = [start_pair(I, Mode, Addr, Node) || I <- Batch],
    _ = [await_ready(P) || P <- Pairs],
    setup_batches(Rest, Mode, Addr, Node, lists:reverse(Pairs, Acc)).

%% @doc Makes N closed-loop counters on this node, kept under Key.
-spec new_counters(term(), pos_integer()) -> ok.
new_counters(Key, N) ->
    persistent_term:put(Key, counters:new(N, [write_concurrency])).

%% @doc The sum of the closed-loop counters kept under Key on this node
%% (counters cannot cross nodes: see bench_requester).
-spec count(term()) -> non_neg_integer().
count(Key) ->
    C = persistent_term:get(Key),
    lists:sum([counters:get(C, I) || I <- lists:seq(1, maps:get(size, counters:info(C)))]).

start_pair(I, Mode, Addr, Node) ->
    case lists:member(Mode, evatar_bench_floor:kinds()) of
        true -> start_floor_pair(I, Mode, Addr);
        false -> start_evatar_pair(I, Mode, Addr, Node)
    end.

start_floor_pair(I, Kind, {Addr, Listen}) ->
    Id = <<"floor-", (integer_to_binary(I))/binary>>,
    {VaDesc, AvDesc} = descriptions(I, <<"floor">>),
    Self = self(),
    Av = proc_lib:spawn(?MODULE, avatar_init, [Self, floor, Addr, Id, AvDesc]),
    {ok, AvSock} = gen_tcp:accept(Listen, ?SETUP_TIMEOUT),
    Va = proc_lib:spawn(?MODULE, va_init, [Self, floor, Addr, Id, VaDesc, I]),
    {ok, VaSock} = gen_tcp:accept(Listen, ?SETUP_TIMEOUT),
    Relays = evatar_bench_floor:relay_pair(VaSock, AvSock, Kind),
    _ = [P ! floor_ready || P <- [Va, Av]],
    #{id => Id, index => I, va => Va, avatar => Av, relays => Relays}.

start_evatar_pair(I, Mode, Addr, Node) ->
    Id = <<"load-", (integer_to_binary(I))/binary>>,
    {ok, _} = evatar:create_pairing(Id, (credentials())#{join_timeout => ?SETUP_TIMEOUT,
                                                          feedback_timeout => 10000}),
    {VaDesc, AvDesc} = descriptions(I, <<"load">>),
    Self = self(),
    Av = proc_lib:spawn(Node, ?MODULE, avatar_init, [Self, Mode, Addr, Id, AvDesc]),
    receive {Av, described} -> ok
    after ?SETUP_TIMEOUT -> error({avatar_not_described, Id})
    end,
    Va = proc_lib:spawn(Node, ?MODULE, va_init, [Self, Mode, Addr, Id, VaDesc, I]),
    #{id => Id, index => I, va => Va, avatar => Av}.

await_ready(#{id := Id, va := Va}) ->
    receive {Va, ready} -> ok
    after ?SETUP_TIMEOUT -> error({not_bound, Id})
    end.

%% ---------------------------------------------------------------------------
%% Joining
%% ---------------------------------------------------------------------------

%% A joined entity: the client process, or the raw socket.
-type conn() :: {client, pid()} | {raw, gen_tcp:socket()} | {direct, evatar:session()}.

join(client, {Ip, Port}, Pairing, Role, Desc) ->
    #{entity_id := Entity} = Desc,
    Cred = cred(Role),
    {ok, C} = agent_bridge_client:connect([{Ip, Port}],
                                          #{pairing => Pairing, role => Role,
                                            entity_id => Entity, credential => Cred}),
    ok = agent_bridge_client:describe(C, Desc),
    {client, C};
join(direct, _Addr, Pairing, Role, Desc) ->
    #{entity_id := Entity} = Desc,
    {ok, Session} = evatar:join(Pairing, Role, Entity, cred(Role)),
    ok = evatar:describe(Session, Desc),
    {direct, Session};
join(floor, {Ip, Port}, _Pairing, _Role, _Desc) ->
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {packet, 4}, {active, false},
                                         {nodelay, true}], 10000),
    {raw, S};
join(raw, {Ip, Port}, Pairing, Role, Desc) ->
    #{entity_id := Entity} = Desc,
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {packet, 4}, {active, false},
                                         {nodelay, true}], 10000),
    Hello = {hello, #{pairing => Pairing, role => Role, entity_id => Entity,
                      credential => cred(Role), protocol_version => 1}},
    ok = gen_tcp:send(S, bil_control:encode(Hello)),
    {ok, Frame} = gen_tcp:recv(S, 0, 10000),
    {ok, {control, {welcome, _}}} = bil_control:parse_frame(Frame, #{}),
    ok = gen_tcp:send(S, bil:encode_description(Desc)),
    {raw, S}.

cred(agent) -> ?AGENT_CRED;
cred(avatar) -> ?AVATAR_CRED.

%% Waits for the Binding report that binds the VA's emulator to the
%% actuator (the Avatar may see an earlier report with only itself); on
%% the floor, for the relays to be in place.
await_bound(floor, _Conn) ->
    receive floor_ready -> ok
    after ?SETUP_TIMEOUT -> error(floor_not_ready)
    end;
await_bound(_Mode, Conn) ->
    await_bound(Conn).

await_bound({client, C}) ->
    receive
        {agent_bridge, C, {binding, Report}} ->
            case bound(Report) of
                true -> ok;
                false -> await_bound({client, C})
            end;
        {agent_bridge, C, {closed, Why}} ->
            error({closed_while_binding, Why})
    after ?SETUP_TIMEOUT -> error(binding_timeout)
    end;
await_bound({direct, _} = Conn) ->
    receive
        {evatar, _, {bound, Report}} ->
            case bound(Report) of
                true -> ok;
                false -> await_bound(Conn)
            end
    after ?SETUP_TIMEOUT -> error(binding_timeout)
    end;
await_bound({raw, S}) ->
    {ok, Frame} = gen_tcp:recv(S, 0, ?SETUP_TIMEOUT),
    case bil_control:parse_frame(Frame, #{}) of
        {ok, {control, {binding, Report}}} ->
            case bound(Report) of
                true -> ok;
                false -> await_bound({raw, S})
            end;
        Other ->
            error({unexpected_while_binding, Other})
    end.

bound(#{bound := Bound}) ->
    lists:any(fun(#{consumer := #{component := C}}) -> C =:= ?VA_COMPONENT end, Bound).

activate({client, _}) -> ok;
activate({direct, _}) -> ok;
activate({raw, S}) ->
    start_reading(S, ?ACTIVE_N).

%% @doc Puts S in `{active, N}' mode, with the count read_on/2 keeps for it.
-spec start_reading(gen_tcp:socket(), pos_integer()) -> ok.
start_reading(S, N) ->
    put({credit, S}, N div 2),
    ok = inet:setopts(S, [{active, N}]).

%% @doc Counts a frame read from S in `{active, N}' mode (the count, one
%% per socket, in the process dictionary of the socket's reader, which may
%% read several sockets) and every half batch
%% tops the socket's count up to N with agent_bridge_conn's transport
%% function: a socket that never goes passive is polled by the runtime's
%% schedulers rather than its poll thread.
-spec read_on(gen_tcp:socket(), pos_integer()) -> ok.
read_on(S, N) ->
    case get({credit, S}) of
        C when C > 1 ->
            put({credit, S}, C - 1),
            ok;
        _ ->
            put({credit, S}, N div 2),
            agent_bridge_transport:top_up({tcp, S}, N)
    end.

%% @doc After a passive notice: reads on unless a top-up came first.
-spec reactivate(gen_tcp:socket(), pos_integer()) -> ok.
reactivate(S, N) ->
    case agent_bridge_transport:is_passive({tcp, S}) of
        true -> start_reading(S, N);
        false -> ok
    end.

%% ---------------------------------------------------------------------------
%% The Avatar: answers every request with a feedback, in its own process
%% ---------------------------------------------------------------------------

%% @private
-spec avatar_init(pid(), mode(), {inet:ip_address(), inet:port_number()}, binary(),
                  bil:description()) -> no_return().
avatar_init(Parent, Mode, Addr, Pairing, Desc) ->
    monitor(process, Parent),
    Conn = join(Mode, Addr, Pairing, avatar, Desc),
    _ = [Parent ! {self(), described} || Mode =/= floor],
    ok = await_bound(Mode, Conn),
    ok = activate(Conn),
    avatar_loop(Conn, feedback_template()).

avatar_loop({client, C} = Conn, T) ->
    receive
        {agent_bridge, C, {signal, #{context := request, id := Id, sender := S,
                                     receiver := R}}} ->
            ok = agent_bridge_client:send(C, #{context => feedback, id => <<"fb-", Id/binary>>,
                                               in_reply_to => Id, sender => R, receiver => S,
                                               body => feedback_body()}),
            avatar_loop(Conn, T);
        {agent_bridge, C, {closed, _}} ->
            exit(normal);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        _Other ->
            avatar_loop(Conn, T)
    end;
avatar_loop({direct, Session} = Conn, T) ->
    receive
        {evatar, _, {signal, #{context := request, id := Id, sender := S, receiver := R}}} ->
            ok = evatar:send(Session, #{context => feedback, id => <<"fb-", Id/binary>>,
                                        in_reply_to => Id, sender => R, receiver => S,
                                        timestamp => os:system_time(millisecond),
                                        seq => undefined, epoch => undefined,
                                        body => feedback_body()}),
            avatar_loop(Conn, T);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        _Other ->
            avatar_loop(Conn, T)
    end;
avatar_loop({raw, S} = Conn, {P1, P2, P3} = T) ->
    receive
        {tcp, S, Frame} ->
            ok = read_on(S, ?ACTIVE_N),
            case binary:match(Frame, <<"<Context>RequestAwaitingFeedback</Context>">>) of
                nomatch ->
                    ok;
                _ ->
                    Id = element_text(Frame, <<"<SignalID>">>, <<"</SignalID>">>),
                    ok = gen_tcp:send(S, [P1, Id, P2, Id, P3])
            end,
            avatar_loop(Conn, T);
        {tcp_passive, S} ->
            ok = reactivate(S, ?ACTIVE_N),
            avatar_loop(Conn, T);
        {tcp_closed, S} ->
            exit(normal);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        _Other ->
            avatar_loop(Conn, T)
    end.

%% The feedback document split around its two ids: the SignalID is
%% `fb-' followed by the request's id, InReplyTo the request's id.
feedback_template() ->
    Doc = iolist_to_binary(
            bil:encode_signal(#{id => <<"fb-@@ID1@@">>, context => feedback,
                                sender => ?AV_COMPONENT, receiver => ?VA_COMPONENT,
                                in_reply_to => <<"@@ID2@@">>,
                                timestamp => os:system_time(millisecond),
                                seq => undefined, epoch => undefined,
                                body => feedback_body()})),
    [P1, Rest] = binary:split(Doc, <<"@@ID1@@">>),
    [P2, P3] = binary:split(Rest, <<"@@ID2@@">>),
    {P1, P2, P3}.

request_template() ->
    Doc = iolist_to_binary(
            bil:encode_signal(#{id => <<"@@ID@@">>, context => request,
                                sender => ?VA_COMPONENT, receiver => ?AV_COMPONENT,
                                in_reply_to => undefined,
                                timestamp => os:system_time(millisecond),
                                seq => undefined, epoch => undefined,
                                body => request_body()})),
    [P1, P2] = binary:split(Doc, <<"@@ID@@">>),
    {P1, P2}.

element_text(Frame, Open, Close) ->
    {Start, Len} = binary:match(Frame, Open),
    From = Start + Len,
    {End, _} = binary:match(Frame, Close, [{scope, {From, byte_size(Frame) - From}}]),
    binary:part(Frame, From, End - From).

%% ---------------------------------------------------------------------------
%% The VA: bench_requester over this connection
%% ---------------------------------------------------------------------------

%% @private
-spec va_init(pid(), mode(), {inet:ip_address(), inet:port_number()}, binary(),
              bil:description(), pos_integer()) -> no_return().
va_init(Parent, Mode, Addr, Pairing, Desc, Index) ->
    monitor(process, Parent),
    Conn = join(Mode, Addr, Pairing, agent, Desc),
    ok = await_bound(Mode, Conn),
    ok = activate(Conn),
    Parent ! {self(), ready},
    Template = request_template(),
    bench_requester:run(#{parent => Parent, index => Index,
                          send => fun(K) ->
                                          Id = <<"q", (integer_to_binary(K))/binary>>,
                                          send_request(Conn, Id, Template)
                                  end,
                          answer => fun(Msg) -> answer(Msg, Conn) end}).

send_request({client, C}, Id, _T) ->
    agent_bridge_client:send(C, #{context => request, id => Id, sender => ?VA_COMPONENT,
                                  receiver => ?AV_COMPONENT, body => request_body()});
send_request({direct, Session}, Id, _T) ->
    evatar:send(Session, #{context => request, id => Id, sender => ?VA_COMPONENT,
                           receiver => ?AV_COMPONENT, in_reply_to => undefined,
                           timestamp => os:system_time(millisecond), seq => undefined,
                           epoch => undefined, body => request_body()});
send_request({raw, S}, Id, {P1, P2}) ->
    gen_tcp:send(S, [P1, Id, P2]).

%% Which request a message answers, and how (see bench_requester).
-spec answer(term(), conn()) -> {pos_integer(), ok | error | timeout} | ignore.
answer({agent_bridge, C, {signal, Signal}}, {client, C}) ->
    answer_kind(Signal);
answer({evatar, _, {signal, Signal}}, {direct, _}) ->
    answer_kind(Signal);
answer({agent_bridge, C, {closed, Why}}, {client, C}) ->
    exit({va_closed, Why});
answer({tcp, S, Frame}, {raw, S}) ->
    ok = read_on(S, ?ACTIVE_N),
    case binary:match(Frame, <<"<InReplyTo>q">>) of
        nomatch ->
            ignore;
        {Pos, Len} ->
            From = Pos + Len,
            {End, _} = binary:match(Frame, <<"<">>, [{scope, {From, byte_size(Frame) - From}}]),
            N = binary_to_integer(binary:part(Frame, From, End - From)),
            Kind = case binary:match(Frame, <<"<Context>Feedback</Context>">>) of
                       nomatch -> error;
                       _ ->
                           case binary:match(Frame, <<"<ServiceCategory>EVATAR<">>) of
                               nomatch -> ok;
                               _ -> timeout
                           end
                   end,
            {N, Kind}
    end;
answer({tcp_passive, S}, {raw, S}) ->
    ok = reactivate(S, ?ACTIVE_N),
    ignore;
answer({tcp_closed, S}, {raw, S}) ->
    exit(va_closed);
answer(_, _Conn) ->
    ignore.

%% @doc A parsed signal that answers request `q<K>': `{K, ok}' for a
%% feedback, `{K, timeout}' for EVATAR's own Timeout feedback (body
%% category EVATAR), `{K, error}' for anything else; `ignore' when it
%% answers no benchmark request.
-spec answer_kind(bil:signal()) -> {pos_integer(), ok | error | timeout} | ignore.
answer_kind(#{in_reply_to := <<"q", N/binary>>, context := Ctx, body := #{category := Cat}}) ->
    Kind = case {Ctx, Cat} of
               {feedback, <<"EVATAR">>} -> timeout;
               {feedback, _} -> ok;
               _ -> error
           end,
    {binary_to_integer(N), Kind};
answer_kind(_) ->
    ignore.

%% ---------------------------------------------------------------------------
%% Flooders (flood_bench)
%% ---------------------------------------------------------------------------

%% `no_read': a VA that sends requests as fast as its socket takes them
%% and never reads its socket; its Avatar answers, so the feedback piles
%% up towards it. `silent': a VA that sends as fast as its socket takes
%% them and reads what comes back, to an Avatar that never answers, so
%% open requests and their feedback timeouts pile up.
-type flood_kind() :: no_read | silent.

%% Counters of a flooder (counters:new(5, [write_concurrency])).
-define(F_SENT, 1).
-define(F_REJOINS, 2).
-define(F_TIMEOUTS, 3).
-define(F_ERRORS, 4).
-define(F_READ, 5).

%% @private
%% A flooding VA: joins over raw TCP and waits until bound, tells Parent
%% `{self(), flooding}', then floods. Its current socket's local address
%% is kept in the public table Tab under its pid, so that the benchmark
%% can find the bridge connection that serves it. A `no_read' VA whose
%% connection is reset (the slow consumer's bound) joins again and goes on.
-spec flood_va_init(pid(), flood_kind(), address(), binary(), bil:description(),
                    #{counters := counters:counters_ref(), table := ets:tid()}) -> no_return().
flood_va_init(Parent, Kind, Addr, Pairing, Desc, Info) ->
    monitor(process, Parent),
    S = flood_join(Kind, Addr, Pairing, Desc, Info),
    Parent ! {self(), flooding},
    flood(Kind, S, request_template(), 1, {Addr, Pairing, Desc, Info}).

flood_join(Kind, Addr, Pairing, Desc, #{table := Tab} = Info) ->
    flood_join(Kind, Addr, Pairing, Desc, Info, Tab, 1000).

flood_join(_Kind, _Addr, Pairing, _Desc, _Info, _Tab, 0) ->
    exit({flooder_cannot_join, Pairing});
flood_join(Kind, {Ip, Port} = Addr, Pairing, #{entity_id := Entity} = Desc, Info, Tab, Tries) ->
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {packet, 4}, {active, false},
                                         {nodelay, true}], 10000),
    Hello = {hello, #{pairing => Pairing, role => agent, entity_id => Entity,
                      credential => cred(agent), protocol_version => 1}},
    ok = gen_tcp:send(S, bil_control:encode(Hello)),
    %% A join right after a reset can meet the entity not yet dropped
    %% (Refused): the next attempt follows the answer, not a timer.
    case gen_tcp:recv(S, 0, 10000) of
        {ok, Frame} ->
            case bil_control:parse_frame(Frame, #{}) of
                {ok, {control, {welcome, _}}} ->
                    ok = gen_tcp:send(S, bil:encode_description(Desc)),
                    ok = await_bound({raw, S}),
                    {ok, Name} = inet:sockname(S),
                    true = ets:insert(Tab, {self(), Name}),
                    ok = case Kind of
                             silent -> start_reader(S, Info);
                             no_read -> ok
                         end,
                    S;
                _Refused ->
                    ok = gen_tcp:close(S),
                    flood_join(Kind, Addr, Pairing, Desc, Info, Tab, Tries - 1)
            end;
        {error, _} ->
            ok = gen_tcp:close(S),
            flood_join(Kind, Addr, Pairing, Desc, Info, Tab, Tries - 1)
    end.

flood(no_read, S, {P1, P2} = T, K, {Addr, Pairing, Desc, #{counters := C} = Info} = Join) ->
    case gen_tcp:send(S, [P1, <<"f", (integer_to_binary(K))/binary>>, P2]) of
        ok ->
            ok = counters:add(C, ?F_SENT, 1),
            flood(no_read, S, T, K + 1, Join);
        {error, _} ->
            _ = gen_tcp:close(S),
            ok = counters:add(C, ?F_REJOINS, 1),
            flood(no_read, flood_join(no_read, Addr, Pairing, Desc, Info), T, K + 1, Join)
    end;
flood(silent, S, {P1, P2} = T, K, {_, _, _, #{counters := C}} = Join) ->
    case gen_tcp:send(S, [P1, <<"f", (integer_to_binary(K))/binary>>, P2]) of
        ok ->
            ok = counters:add(C, ?F_SENT, 1),
            flood(silent, S, T, K + 1, Join);
        {error, Why} ->
            exit({flooder_closed, Why})
    end.

%% The silent VA reads in a process of its own, the socket's owner: a
%% sender blocked in gen_tcp:send while EVATAR holds back its reads
%% (docs/protocol.md section 8) would otherwise stop reading too and be
%% reset as a slow consumer, which is the other flooder's case.
start_reader(S, #{counters := C}) ->
    Reader = spawn_link(fun() ->
                                receive {go, S} -> ok end,
                                ok = start_reading(S, ?ACTIVE_N),
                                read_answers(S, C)
                        end),
    ok = gen_tcp:controlling_process(S, Reader),
    Reader ! {go, S},
    ok.

%% What comes back, counted: EVATAR's Timeout feedbacks, and every other
%% frame that answers a request (TooManyRequests errors).
read_answers(S, C) ->
    receive
        {tcp, S, Frame} ->
            ok = read_on(S, ?ACTIVE_N),
            ok = counters:add(C, ?F_READ, 1),
            _ = case {binary:match(Frame, <<"<InReplyTo>f">>),
                      binary:match(Frame, <<"<ServiceCategory>EVATAR<">>),
                      binary:match(Frame, <<"<Context>Feedback</Context>">>)} of
                    {nomatch, _, _} -> ok;
                    {_, nomatch, _} -> counters:add(C, ?F_ERRORS, 1);
                    {_, _, nomatch} -> counters:add(C, ?F_ERRORS, 1);
                    _ -> counters:add(C, ?F_TIMEOUTS, 1)
                end,
            read_answers(S, C);
        {tcp_passive, S} ->
            ok = reactivate(S, ?ACTIVE_N),
            read_answers(S, C);
        {tcp_closed, S} ->
            exit(flooder_closed)
    end.

%% @private
%% An Avatar that joins over raw TCP, describes itself, reads everything
%% and never answers.
-spec silent_avatar_init(pid(), address(), binary(), bil:description()) -> no_return().
silent_avatar_init(Parent, Addr, Pairing, Desc) ->
    monitor(process, Parent),
    {raw, S} = Conn = join(raw, Addr, Pairing, avatar, Desc),
    Parent ! {self(), described},
    ok = await_bound(raw, Conn),
    ok = activate(Conn),
    silent_loop(S).

silent_loop(S) ->
    receive
        {tcp, S, _Frame} ->
            ok = read_on(S, ?ACTIVE_N),
            silent_loop(S);
        {tcp_passive, S} ->
            ok = reactivate(S, ?ACTIVE_N),
            silent_loop(S);
        {tcp_closed, S} ->
            exit(normal);
        {'DOWN', _, process, _, _} ->
            exit(normal)
    end.

%% ---------------------------------------------------------------------------
%% Idle pairings
%% ---------------------------------------------------------------------------

%% @doc Joins pairing I's VA and Avatar with agent_bridge_client, both
%% owned by Sink, and returns the two client processes once the VA is
%% bound. For the idle measurement: nothing is sent afterwards.
%% `Evatar' is the node whose pairing is checked for the binding.
-spec idle_join(pos_integer(), pid(), {inet:ip_address(), inet:port_number()}, node()) ->
          {pid(), pid()}.
idle_join(I, Sink, {Ip, Port}, Evatar) ->
    Id = <<"idle-", (integer_to_binary(I))/binary>>,
    {VaDesc, AvDesc} = descriptions(I, <<"idle">>),
    Connect = fun(Role, #{entity_id := E} = Desc) ->
                      {ok, C} = agent_bridge_client:connect(
                                  [{Ip, Port}], #{pairing => Id, role => Role, entity_id => E,
                                                  credential => cred(Role), owner => Sink}),
                      ok = agent_bridge_client:describe(C, Desc),
                      C
              end,
    Av = Connect(avatar, AvDesc),
    Va = Connect(agent, VaDesc),
    ok = await_idle_bound(Id, Evatar, 2000),
    {Va, Av}.

%% The clients' owner is the sink, so binding is checked on the pairing.
await_idle_bound(Id, _, 0) -> error({not_bound, Id});
await_idle_bound(Id, Evatar, Tries) ->
    case erpc:call(Evatar, evatar, bindings, [Id]) of
        {ok, Report} ->
            case bound(Report) of
                true -> ok;
                false -> timer:sleep(5), await_idle_bound(Id, Evatar, Tries - 1)
            end;
        {error, not_found} ->
            error({no_pairing, Id})
    end.

%% @doc A process that owns idle clients and drops what they send it.
-spec sink() -> no_return().
sink() ->
    receive
        stop -> exit(normal);
        _ -> sink()
    end.
