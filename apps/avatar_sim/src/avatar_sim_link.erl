%% @doc Internal. One simulated device's connection to EVATAR, as device
%% software would hold it: `agent_bridge_client' with role avatar, the
%% description sent after every (re)connection, requests passed to the world,
%% answers and sensor signals sent back. It learns from each Binding report
%% which VA component each of its sensors feeds. Failure hooks: muted
%% components swallow requests; the link can drop its connection and stay
%% away; detached components are left out of the description.
%%
%% ```
%%  connecting --Welcome, described--> connected --closed/refused--> retrying
%%      ^  |  all endpoints failed          |                          |
%%      |  +------------------------------> retrying <-----------------+
%%      +---------- backoff elapsed --------+
%%  connected/retrying --disconnect--> away --reconnect / away time over--> connecting
%% '''
-module(avatar_sim_link).
-behaviour(gen_statem).

-export([start_link/2, emit/3, mute/3, disconnect/2, reconnect/1, detach/3, info/1]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([opts/0]).

-type opts() :: #{entity := binary(),
                  description := bil:description(),
                  pairing => binary(),
                  credential => binary(),
                  endpoints => [agent_bridge_client:endpoint()],
                  retry => pos_integer()}.

%% The states of the machine (the diagram above).
-type state() :: connecting | connected | retrying | away.

-define(MAX_RETRY, 5000).
%% A link may be busy for a connect and handshake timeout (5 s each).
-define(CALL, 20000).

-record(d, {world :: pid(),
            entity :: binary(),
            opts :: opts(),
            client :: pid() | undefined,
            %% {SenderComponent, ConsumesType} -> ProviderComponent
            routes = #{} :: #{{binary(), binary()} => binary()},
            muted = [] :: [binary()],
            detached = [] :: [binary()],
            backoff :: pos_integer(),
            sent = 0 :: non_neg_integer(),
            unrouted = 0 :: non_neg_integer(),
            %% On this connection: the Sequence of the last signal passed to
            %% the world (or swallowed), and signals sent.
            in = 0 :: non_neg_integer(),
            out = 0 :: non_neg_integer()}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

-spec start_link(pid(), opts()) -> {ok, pid()}.
start_link(World, Opts) ->
    gen_statem:start_link(?MODULE, {World, Opts}, []).

%% @doc Sends an answer (receiver set) or a sensor push (receiver found in
%% the bindings); dropped when not connected or not bound.
-spec emit(pid(), answer | push, agent_bridge_client:partial_signal() | map()) -> ok.
emit(Link, Kind, Signal) -> gen_statem:cast(Link, {emit, Kind, Signal}).

-spec mute(pid(), binary(), boolean()) -> ok.
mute(Link, Component, On) -> gen_statem:call(Link, {mute, Component, On}, ?CALL).

%% @doc Drops the connection without a Bye and stays away, for `Ms' real
%% milliseconds or until {@link reconnect/1}.
-spec disconnect(pid(), timeout()) -> ok.
disconnect(Link, Ms) -> gen_statem:call(Link, {disconnect, Ms}, ?CALL).

-spec reconnect(pid()) -> ok.
reconnect(Link) -> gen_statem:call(Link, reconnect, ?CALL).

%% @doc Leaves a component out of the description (`true') or puts it back,
%% describing again at once when connected.
-spec detach(pid(), binary(), boolean()) -> ok.
detach(Link, Component, On) -> gen_statem:call(Link, {detach, Component, On}, ?CALL).

%% @doc The link's state and counts; `in' (the Sequence of the last signal
%% from EVATAR taken) and `out' (signals sent) are of the current
%% connection, what evatar:traffic/1 counts on the pairing's side.
-spec info(pid()) -> map().
info(Link) -> gen_statem:call(Link, info, ?CALL).

%% ---------------------------------------------------------------------------
%% gen_statem
%% ---------------------------------------------------------------------------

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init({pid(), opts()}) -> gen_statem:init_result(state()).
init({World, #{entity := Entity} = Opts}) ->
    %% So that terminate/3 says Bye when the Avatar is stopped.
    process_flag(trap_exit, true),
    logger:update_process_metadata(#{domain => [avatar_sim, link], entity => Entity}),
    ok = avatar_sim_world:link_up(World, Entity, self()),
    D = #d{world = World, entity = Entity, opts = Opts, backoff = maps:get(retry, Opts, 200)},
    case maps:is_key(pairing, Opts) of
        true -> {ok, connecting, D, [{next_event, internal, connect}]};
        false -> {ok, away, D}
    end.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(internal, connect, connecting, #d{opts = Opts, entity = Entity} = D) ->
    ClientOpts = #{pairing => maps:get(pairing, Opts), role => avatar, entity_id => Entity,
                   credential => maps:get(credential, Opts, <<>>), owner => self()},
    Endpoints = maps:get(endpoints, Opts, [{{127, 0, 0, 1}, 7400}]),
    case agent_bridge_client:connect(Endpoints, ClientOpts) of
        {ok, Client} ->
            monitor(process, Client),
            case agent_bridge_client:describe(Client, description(D)) of
                ok ->
                    logger:info(#{what => avatar_connected, entity => Entity}),
                    {next_state, connected,
                     D#d{client = Client, routes = #{}, backoff = maps:get(retry, Opts, 200),
                         in = 0, out = 0}};
                {error, closed} ->
                    retry(connect_closed, D)
            end;
        {error, Why} ->
            retry(Why, D)
    end;
handle_event(state_timeout, retry, retrying, D) ->
    {next_state, connecting, D, [{next_event, internal, connect}]};
handle_event(state_timeout, back, away, D) ->
    {next_state, connecting, D, [{next_event, internal, connect}]};

handle_event(info, {agent_bridge, C, {signal, Signal}}, connected, #d{client = C} = D) ->
    case lists:member(maps:get(receiver, Signal), D#d.muted) of
        true -> ok;
        false -> avatar_sim_world:incoming(D#d.world, D#d.entity, Signal)
    end,
    {keep_state, D#d{in = case Signal of
                              #{seq := Seq} when is_integer(Seq) -> Seq;
                              #{} -> D#d.in
                          end}};
handle_event(info, {agent_bridge, C, {binding, Report}}, connected, #d{client = C} = D) ->
    Routes = routes(Report, D#d.entity),
    New = [Key || Key <- maps:keys(Routes), not maps:is_key(Key, D#d.routes)],
    case New of
        [] -> ok;
        _ -> avatar_sim_world:link_bound(D#d.world, D#d.entity, lists:sort(New))
    end,
    {keep_state, D#d{routes = Routes}};
handle_event(info, {agent_bridge, C, {closed, Reason}}, connected, #d{client = C} = D) ->
    retry(Reason, D#d{client = undefined});
handle_event(info, {agent_bridge, _, _}, _State, _D) ->
    keep_state_and_data;
handle_event(info, {'DOWN', _, process, C, Why}, connected, #d{client = C} = D) ->
    retry({client_down, Why}, D#d{client = undefined});
handle_event(info, {'DOWN', _, process, _, _}, _State, _D) ->
    keep_state_and_data;

handle_event(cast, {emit, Kind, Signal}, connected, D) ->
    case receiver(Kind, Signal, D) of
        {ok, Receiver} ->
            case agent_bridge_client:send(D#d.client, Signal#{receiver => Receiver}) of
                ok -> {keep_state, D#d{sent = D#d.sent + 1, out = D#d.out + 1}};
                {error, _} -> {keep_state, D#d{sent = D#d.sent + 1}}
            end;
        none ->
            {keep_state, D#d{unrouted = D#d.unrouted + 1}}
    end;
handle_event(cast, {emit, _Kind, _Signal}, _State, D) ->
    {keep_state, D#d{unrouted = D#d.unrouted + 1}};

handle_event({call, From}, {mute, Component, true}, _State, D) ->
    {keep_state, D#d{muted = lists:usort([Component | D#d.muted])}, [{reply, From, ok}]};
handle_event({call, From}, {mute, Component, false}, _State, D) ->
    {keep_state, D#d{muted = lists:delete(Component, D#d.muted)}, [{reply, From, ok}]};
handle_event({call, From}, {disconnect, Ms}, _State, D) ->
    D1 = drop_client(D),
    Timeout = case Ms of infinity -> []; _ -> [{state_timeout, Ms, back}] end,
    {next_state, away, D1, [{reply, From, ok} | Timeout]};
handle_event({call, From}, reconnect, away, D) ->
    {next_state, connecting, D, [{reply, From, ok}, {next_event, internal, connect}]};
handle_event({call, From}, reconnect, _State, _D) ->
    {keep_state_and_data, [{reply, From, ok}]};
handle_event({call, From}, {detach, Component, On}, State, D) ->
    Detached = case On of
                   true -> lists:usort([Component | D#d.detached]);
                   false -> lists:delete(Component, D#d.detached)
               end,
    D1 = D#d{detached = Detached},
    _ = case State of
            connected -> agent_bridge_client:describe(D1#d.client, description(D1));
            _ -> ok
        end,
    {keep_state, D1, [{reply, From, ok}]};
handle_event({call, From}, info, State, D) ->
    Info = #{entity => D#d.entity, pairing => maps:get(pairing, D#d.opts, undefined),
             state => State, muted => D#d.muted, detached => D#d.detached,
             sent => D#d.sent, unrouted => D#d.unrouted, in => D#d.in, out => D#d.out,
             routes => maps:size(D#d.routes)},
    {keep_state_and_data, [{reply, From, Info}]}.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Why, _State, #d{client = undefined}) -> ok;
terminate(_Why, _State, #d{client = Client}) -> agent_bridge_client:close(Client).

%% ---------------------------------------------------------------------------
%% Internals
%% ---------------------------------------------------------------------------

description(#d{opts = #{description := Desc}, detached = Detached}) ->
    avatar_sim_desc:without(Desc, Detached).

retry(Why, #d{backoff = B} = D) ->
    logger:info(#{what => avatar_link_retry, entity => D#d.entity, reason => Why,
                  after_ms => B}),
    {next_state, retrying, D#d{routes = #{}, backoff = min(2 * B, ?MAX_RETRY)},
     [{state_timeout, B, retry}]}.

%% As if the device lost power: no Bye, the socket just goes.
drop_client(#d{client = undefined} = D) -> D;
drop_client(#d{client = C} = D) ->
    exit(C, kill),
    D#d{client = undefined, routes = #{}}.

routes(#{bound := Bound}, Entity) ->
    maps:from_list([{{C, T}, P} || #{consumer := #{entity := E, component := C},
                                     provider := #{component := P}, type := T} <- Bound,
                                   E =:= Entity]).

receiver(answer, #{receiver := R}, _D) -> {ok, R};
receiver(push, #{sender := C, body := #{type := T}}, #d{routes = Routes}) ->
    case Routes of
        #{{C, T} := P} -> {ok, P};
        #{} -> none
    end.
