%% @doc Erlang client of the EVATAR wire protocol (docs/protocol.md): joins
%% a pairing as a VA or an Avatar over TCP, sends descriptions and signals,
%% and passes what EVATAR sends to an owner process as messages:
%% `{agent_bridge, Client, {signal, Signal}}',
%% `{agent_bridge, Client, {binding, Report}}' and, last,
%% `{agent_bridge, Client, {closed, Reason}}'.
%%
%% ```
%%  connecting --TCP up, Hello sent--> handshaking --Welcome--> connected
%%      ^   | all endpoints failed           | Refused          | closed, Refused, Bye
%%      |   v                                v                  v
%%      +-- next endpoint on failure      (stop)      disconnected hook (stop)
%% '''
-module(agent_bridge_client).
-behaviour(gen_statem).

-export([connect/2, describe/2, send/2, request/3, close/1, session/1]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([opts/0, endpoint/0, close_reason/0, partial_signal/0]).

-type endpoint() :: {inet:socket_address() | inet:hostname(), inet:port_number()}.
-type opts() :: #{pairing := binary(),
                  role := agent | avatar,
                  entity_id := binary(),
                  credential := binary(),
                  owner => pid(),
                  connect_timeout => timeout(),
                  handshake_timeout => timeout(),
                  max_frame => pos_integer(),
                  active_n => pos_integer()}.
%% A signal with `id', `timestamp', `in_reply_to', `seq' and `epoch' left
%% out; the client fills them in.
-type partial_signal() :: #{context => bil:signal_context(),
                            sender := binary(),
                            receiver := binary(),
                            body := bil:entry(),
                            id => binary(),
                            in_reply_to => binary() | undefined,
                            timestamp => non_neg_integer(),
                            seq => non_neg_integer() | undefined,
                            epoch => non_neg_integer() | undefined}.
-type close_reason() :: closed | normal
                      | {refused, Code :: binary(), Message :: binary()}
                      | {bye, binary()}
                      | {malformed, bil:error_reason()}
                      | {socket_error, term()}.

-record(d, {opts :: opts(),
            owner :: pid(),
            endpoints :: [endpoint()],
            failures = [] :: [{endpoint(), term()}],
            current :: endpoint() | undefined,
            sock :: gen_tcp:socket() | undefined,
            waiter :: gen_statem:from() | undefined,
            welcome :: bil_control:welcome() | undefined,
            nonce :: binary(),
            counter = 0 :: non_neg_integer(),
            pending = #{} :: #{binary() => gen_statem:from()}}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Connects to the first endpoint that answers and completes the
%% handshake. A Refused ends the attempt at once: the same credential would
%% be refused elsewhere too.
-spec connect([endpoint()], opts()) ->
          {ok, pid()} | {error, {refused, binary(), binary()}
                                | {unreachable, [{endpoint(), term()}]}}.
connect(Endpoints, Opts) ->
    Owner = maps:get(owner, Opts, self()),
    {ok, Pid} = gen_statem:start(?MODULE, {Endpoints, Opts, Owner}, []),
    gen_statem:call(Pid, await_welcome).

%% @doc Sends a description; returns once written. The Binding report comes
%% later as a message.
-spec describe(pid(), bil:description()) -> ok | {error, closed}.
describe(Client, Description) ->
    call(Client, {frame, bil:encode_description(Description)}).

%% @doc Sends a signal, filling in what the caller left out.
-spec send(pid(), partial_signal()) -> ok | {error, closed}.
send(Client, Signal) ->
    call(Client, {signal, Signal}).

%% @doc Sends a request awaiting feedback and waits for the answer:
%% `{ok, Feedback}' (possibly EVATAR's own Timeout feedback: body category
%% EVATAR, type Timeout), `{error, Signal}' for an error signal answering
%% it, `{error, timeout}' when nothing came within Timeout ms. Progress
%% signals reach the owner as usual.
-spec request(pid(), partial_signal(), timeout()) ->
          {ok, bil:signal()} | {error, timeout | closed | bil:signal()}.
request(Client, Signal, Timeout) ->
    call(Client, {request, Signal, Timeout}).

%% @doc Says Bye and closes.
-spec close(pid()) -> ok.
close(Client) ->
    case call(Client, close) of
        ok -> ok;
        {error, closed} -> ok
    end.

%% @doc The Welcome of the current session.
-spec session(pid()) -> {ok, bil_control:welcome()} | {error, closed}.
session(Client) -> call(Client, session).

call(Client, Request) ->
    try gen_statem:call(Client, Request)
    catch exit:{noproc, _} -> {error, closed};
          exit:{normal, _} -> {error, closed}
    end.

%% ---------------------------------------------------------------------------
%% States
%% ---------------------------------------------------------------------------

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init({[endpoint()], opts(), pid()}) -> gen_statem:init_result(connecting).
init({Endpoints, Opts, Owner}) ->
    monitor(process, Owner),
    D = #d{opts = Opts, owner = Owner, endpoints = Endpoints,
           nonce = binary:encode_hex(crypto:strong_rand_bytes(4))},
    {ok, connecting, D}.

-spec handle_event(gen_statem:event_type(), term(), atom(), #d{}) ->
          gen_statem:event_handler_result(atom()).
handle_event({call, From}, await_welcome, connected, _D) ->
    {keep_state_and_data, [{reply, From, {ok, self()}}]};
handle_event({call, From}, await_welcome, connecting, #d{waiter = undefined} = D) ->
    %% Connecting starts only now, so the outcome always has a caller to go to.
    {keep_state, D#d{waiter = From}, [{next_event, internal, connect}]};
handle_event(internal, connect, connecting, #d{endpoints = []} = D) ->
    fail({unreachable, lists:reverse(D#d.failures)}, D);
handle_event(internal, connect, connecting, #d{endpoints = [{Host, Port} = E | Rest]} = D) ->
    Opts = D#d.opts,
    SockOpts = [binary, {packet, 4}, {packet_size, maps:get(max_frame, Opts, 1048576)},
                {active, once}, {nodelay, true}],
    case gen_tcp:connect(Host, Port, SockOpts, maps:get(connect_timeout, Opts, 5000)) of
        {ok, Sock} ->
            Hello = {hello, #{pairing => maps:get(pairing, Opts), role => maps:get(role, Opts),
                              entity_id => maps:get(entity_id, Opts),
                              credential => maps:get(credential, Opts),
                              protocol_version => 1}},
            case gen_tcp:send(Sock, bil_control:encode(Hello)) of
                ok ->
                    {next_state, handshaking, D#d{sock = Sock, endpoints = Rest, current = E},
                     [{state_timeout, maps:get(handshake_timeout, Opts, 5000), E}]};
                {error, Why} ->
                    gen_tcp:close(Sock),
                    next_endpoint(E, Why, D#d{endpoints = Rest})
            end;
        {error, Why} ->
            next_endpoint(E, Why, D#d{endpoints = Rest})
    end;
handle_event(state_timeout, E, handshaking, D) ->
    gen_tcp:close(D#d.sock),
    next_endpoint(E, handshake_timeout, D#d{sock = undefined});
handle_event(info, {tcp, Sock, Frame}, handshaking, #d{sock = Sock} = D) ->
    case bil_control:parse_frame(Frame, #{}) of
        {ok, {control, {welcome, Welcome}}} ->
            ok = inet:setopts(Sock, [{active, maps:get(active_n, D#d.opts, 32)}]),
            reply_waiter({ok, self()}, D),
            {next_state, connected, D#d{welcome = Welcome, waiter = undefined}};
        {ok, {control, {refused, #{code := Code, message := Message}}}} ->
            fail({refused, Code, Message}, D);
        {ok, Other} ->
            fail({refused, <<"BadHandshake">>,
                  iolist_to_binary(io_lib:format("expected Welcome, got ~p", [Other]))}, D);
        {error, Reason} ->
            fail({refused, <<"Malformed">>, bil:format_error(Reason)}, D)
    end;
handle_event(info, {tcp_closed, Sock}, handshaking, #d{sock = Sock} = D) ->
    next_endpoint(D#d.current, closed, D#d{sock = undefined});
handle_event(info, {tcp_error, Sock, Why}, handshaking, #d{sock = Sock} = D) ->
    next_endpoint(D#d.current, Why, D#d{sock = undefined});

%% Connected.
handle_event(info, {tcp, Sock, Frame}, connected, #d{sock = Sock} = D) ->
    incoming(bil_control:parse_frame(Frame, #{}), D);
handle_event(info, {tcp_passive, Sock}, connected, #d{sock = Sock} = D) ->
    ok = inet:setopts(Sock, [{active, maps:get(active_n, D#d.opts, 32)}]),
    keep_state_and_data;
handle_event(info, {tcp_closed, Sock}, connected, #d{sock = Sock} = D) ->
    disconnected(closed, D);
handle_event(info, {tcp_error, Sock, Why}, connected, #d{sock = Sock} = D) ->
    disconnected({socket_error, Why}, D);
handle_event({call, From}, {frame, Doc}, connected, D) ->
    {keep_state_and_data, [{reply, From, write(Doc, D)}]};
handle_event({call, From}, {signal, Partial}, connected, D) ->
    {Signal, D1} = complete(Partial, D),
    {keep_state, D1, [{reply, From, write(bil:encode_signal(Signal), D1)}]};
handle_event({call, From}, {request, Partial, Timeout}, connected, D) ->
    {#{id := Id} = Signal, D1} = complete(Partial#{context => request}, D),
    case write(bil:encode_signal(Signal), D1) of
        ok ->
            {keep_state, D1#d{pending = maps:put(Id, From, D1#d.pending)},
             [{{timeout, {request, Id}}, Timeout, Id}]};
        {error, _} = Error ->
            {keep_state, D1, [{reply, From, Error}]}
    end;
handle_event({timeout, {request, Id}}, Id, _State, D) ->
    answer(Id, {error, timeout}, D);
handle_event({call, From}, session, connected, #d{welcome = W}) ->
    {keep_state_and_data, [{reply, From, {ok, W}}]};
handle_event({call, From}, close, connected, #d{sock = Sock} = D) ->
    %% The server answers Bye and closes at once, so either call may find
    %% the socket already closed.
    _ = gen_tcp:send(Sock, bil_control:encode({bye, <<>>})),
    _ = gen_tcp:shutdown(Sock, write),
    {stop_and_reply, normal, [{reply, From, ok}], notify({closed, normal}, D)};
handle_event({call, From}, _Request, _State, _D) ->
    {keep_state_and_data, [{reply, From, {error, closed}}]};
handle_event(info, {'DOWN', _, process, Owner, _}, _State, #d{owner = Owner} = D) ->
    {stop, normal, D};
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), atom(), #d{}) -> ok.
terminate(_Why, _State, #d{sock = undefined}) -> ok;
terminate(_Why, _State, #d{sock = Sock}) -> gen_tcp:close(Sock).

%% ---------------------------------------------------------------------------
%% Internals
%% ---------------------------------------------------------------------------

next_endpoint(E, Why, D) ->
    {next_state, connecting, D#d{failures = [{E, Why} | D#d.failures]},
     [{next_event, internal, connect}]}.

fail(Reason, D) ->
    reply_waiter({error, Reason}, D),
    {stop, normal, D#d{waiter = undefined}}.

reply_waiter(_Reply, #d{waiter = undefined}) -> ok;
reply_waiter(Reply, #d{waiter = From}) -> gen_statem:reply(From, Reply).

incoming({ok, {signal, #{in_reply_to := Id, context := Ctx} = S}}, #d{pending = P} = D)
  when is_map_key(Id, P), (Ctx =:= feedback orelse Ctx =:= error) ->
    answer(Id, case Ctx of feedback -> {ok, S}; error -> {error, S} end, D);
incoming({ok, {signal, S}}, D) ->
    {keep_state, notify({signal, S}, D)};
incoming({ok, {control, {binding, Report}}}, D) ->
    {keep_state, notify({binding, Report}, D)};
incoming({ok, {control, {refused, #{code := Code, message := Message}}}}, D) ->
    disconnected({refused, Code, Message}, D);
incoming({ok, {control, {bye, Reason}}}, D) ->
    disconnected({bye, Reason}, D);
incoming({ok, Other}, D) ->
    logger:notice(#{what => unexpected_document, document => Other}),
    {keep_state, D};
incoming({error, Reason}, D) ->
    disconnected({malformed, Reason}, D).

answer(Id, Reply, #d{pending = P} = D) ->
    case maps:take(Id, P) of
        {From, P1} ->
            {keep_state, D#d{pending = P1},
             [{reply, From, Reply}, {{timeout, {request, Id}}, cancel}]};
        error ->
            keep_state_and_data
    end.

%% Issue 5 hooks in here: instead of stopping, reconnect through the
%% endpoint list and resume with the Welcome's SessionID.
disconnected(Reason, #d{pending = P} = D) ->
    _ = [gen_statem:reply(From, {error, closed}) || From <- maps:values(P)],
    {stop, normal, notify({closed, Reason}, D#d{pending = #{}})}.

notify(Event, #d{owner = Owner} = D) ->
    Owner ! {agent_bridge, self(), Event},
    D.

write(Doc, #d{sock = Sock}) ->
    case gen_tcp:send(Sock, Doc) of
        ok -> ok;
        {error, _} -> {error, closed}
    end.

complete(Partial, #d{opts = Opts, nonce = Nonce, counter = N} = D) ->
    Defaults = #{context => request_no_feedback,
                 id => iolist_to_binary([maps:get(entity_id, Opts), "-", Nonce, "-",
                                         integer_to_binary(N + 1)]),
                 timestamp => os:system_time(millisecond),
                 in_reply_to => undefined, seq => undefined, epoch => undefined},
    {maps:merge(Defaults, Partial), D#d{counter = N + 1}}.
