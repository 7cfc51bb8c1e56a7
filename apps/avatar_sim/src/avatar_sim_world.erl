%% @doc Internal. The process of one simulated world (the arena with its
%% robots, or the house with its devices and people): it runs a pure model
%% (a module with the callbacks below) on the clock's ticks and on the
%% requests its links pass in, and carries out the model's effects: answers
%% and sensor signals go out through the link owning the component, files
%% are written. Every emitted signal is logged, so two runs can be compared.
%%
%% ```
%%  subscribing --subscribed to the clock--> running
%%                                            |  tick: model tick, effects, ack
%%                                            |  request from a link: model request, effects
%% '''
-module(avatar_sim_world).
-behaviour(gen_statem).

-export([start_link/1, call/2, incoming/3, link_up/3, link_bound/3]).
-export([init/1, callback_mode/0, handle_event/4]).

-export_type([effect/0, link_spec/0, args/0]).

-type effect() :: {answer, bil:signal(), feedback | progress | error, bil:entry()}
                | {push, Component :: binary(), sensor_data | event, bil:entry()}
                | {file, file:filename_all(), iodata()}.
-type link_spec() :: #{entity := binary(), description := bil:description(), atom() => term()}.
-type args() :: #{model := module(), model_opts := map(), clock := avatar_sim_clock:clock(),
                  links := [link_spec()]}.

-callback init(Opts :: map(), Now :: integer()) -> Model :: term().
-callback tick(Now :: integer(), Model :: term()) -> {term(), [effect()]}.
-callback request(bil:signal(), Now :: integer(), Model :: term()) -> {term(), [effect()]}.
-callback bound(Component :: binary(), ConsumesType :: binary(), Now :: integer(),
                Model :: term()) -> {term(), [effect()]}.
-callback command(Command :: term(), Now :: integer(), Model :: term()) ->
    {Reply :: term(), term(), [effect()]}.
-callback state(Now :: integer(), Model :: term()) -> map().

%% The states of the machine (the diagram above).
-type state() :: subscribing | running.

-define(MAX_LOG, 200000).

-record(d, {model :: module(),
            state :: term(),
            clock :: avatar_sim_clock:clock(),
            owner :: #{binary() => binary()},          % component -> entity
            links = #{} :: #{binary() => pid()},       % entity -> link
            log = [] :: [map()],
            logged = 0 :: non_neg_integer()}).

%% ---------------------------------------------------------------------------
%% API (for avatar_sim and avatar_sim_link)
%% ---------------------------------------------------------------------------

-spec start_link(args()) -> {ok, pid()}.
start_link(Args) ->
    gen_statem:start_link(?MODULE, Args, []).

%% @doc A synchronous request to the world (inspection, hooks, commands).
-spec call(pid(), term()) -> term().
call(World, Request) -> gen_statem:call(World, Request, 30000).

%% @doc A signal EVATAR delivered to one of the link's components.
-spec incoming(pid(), binary(), bil:signal()) -> ok.
incoming(World, Entity, Signal) -> gen_statem:cast(World, {incoming, Entity, Signal}).

-spec link_up(pid(), binary(), pid()) -> ok.
link_up(World, Entity, Link) -> gen_statem:cast(World, {link_up, Entity, Link}).

%% @doc Consumer entries of the link's components that have just become bound.
-spec link_bound(pid(), binary(), [{binary(), binary()}]) -> ok.
link_bound(World, Entity, Entries) -> gen_statem:cast(World, {link_bound, Entity, Entries}).

%% ---------------------------------------------------------------------------
%% gen_statem
%% ---------------------------------------------------------------------------

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init(args()) -> gen_statem:init_result(state()).
init(#{model := Model, model_opts := Opts, clock := Clock, links := Links}) ->
    Owner = maps:from_list([{C, E} || #{entity := E, description := Desc} <- Links,
                                      C <- avatar_sim_desc:component_ids(Desc)]),
    logger:update_process_metadata(#{domain => [avatar_sim], model => Model}),
    State = Model:init(Opts, avatar_sim_clock:now(Clock)),
    {ok, subscribing, #d{model = Model, state = State, clock = Clock, owner = Owner},
     [{next_event, internal, subscribe}]}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(internal, subscribe, subscribing, #d{clock = Clock} = D) ->
    monitor(process, avatar_sim_clock:pid(Clock)),
    ok = avatar_sim_clock:subscribe(Clock, self()),
    {next_state, running, D};
handle_event(info, {avatar_sim_clock, Ref, Now}, _State, #d{model = M, clock = Clock} = D) ->
    {S1, Effects} = M:tick(Now, D#d.state),
    D1 = effects(Effects, Now, D#d{state = S1}),
    ok = avatar_sim_clock:ack(Clock, Ref),
    {keep_state, D1};
handle_event(info, {'DOWN', _, process, Pid, Why}, _State, #d{clock = Clock} = D) ->
    case avatar_sim_clock:pid(Clock) of
        Pid -> {stop, {clock_down, Why}};
        _ -> {keep_state, D#d{links = maps:filter(fun(_, L) -> L =/= Pid end, D#d.links)}}
    end;
handle_event(cast, {link_up, Entity, Link}, _State, D) ->
    monitor(process, Link),
    {keep_state, D#d{links = (D#d.links)#{Entity => Link}}};
handle_event(cast, {link_bound, _Entity, Entries}, _State, #d{model = M} = D) ->
    Now = now(D),
    D1 = lists:foldl(fun({Component, Type}, Acc) ->
                             {S1, Effects} = M:bound(Component, Type, Now, Acc#d.state),
                             effects(Effects, Now, Acc#d{state = S1})
                     end, D, Entries),
    {keep_state, D1};
handle_event(cast, {incoming, Entity, #{context := Ctx} = Signal}, _State, #d{model = M} = D)
  when Ctx =:= request; Ctx =:= request_no_feedback ->
    Now = now(D),
    {S1, Effects} = M:request(Signal, Now, D#d.state),
    logger:debug(#{what => request, entity => Entity, context => Ctx,
                   signal => maps:get(id, Signal)}),
    {keep_state, effects(Effects, Now, D#d{state = S1})};
handle_event(cast, {incoming, Entity, Signal}, _State, _D) ->
    %% Errors from EVATAR about what we sent, mostly: worth a line in the log.
    logger:notice(#{what => unexpected_signal, entity => Entity,
                    context => maps:get(context, Signal), body => maps:get(body, Signal)}),
    keep_state_and_data;
handle_event({call, From}, state, _State, #d{model = M} = D) ->
    {keep_state_and_data, [{reply, From, M:state(now(D), D#d.state)}]};
handle_event({call, From}, scene, _State, #d{model = M} = D) ->
    {keep_state_and_data, [{reply, From, {M, M:state(now(D), D#d.state)}}]};
handle_event({call, From}, log, _State, D) ->
    {keep_state_and_data, [{reply, From, lists:reverse(D#d.log)}]};
handle_event({call, From}, clock, _State, D) ->
    {keep_state_and_data, [{reply, From, D#d.clock}]};
handle_event({call, From}, links, _State, D) ->
    {keep_state_and_data, [{reply, From, D#d.links}]};
handle_event({call, From}, {owner, Component}, _State, D) ->
    Reply = case D#d.owner of
                #{Component := Entity} -> link_of(Entity, D);
                #{} -> {error, unknown_component}
            end,
    {keep_state_and_data, [{reply, From, Reply}]};
handle_event({call, From}, {link, Entity}, _State, D) ->
    {keep_state_and_data, [{reply, From, link_of(Entity, D)}]};
handle_event({call, From}, {command, Command}, _State, #d{model = M} = D) ->
    Now = now(D),
    {Reply, S1, Effects} = M:command(Command, Now, D#d.state),
    {keep_state, effects(Effects, Now, D#d{state = S1}), [{reply, From, Reply}]};
handle_event({call, _From}, _Request, subscribing, _D) ->
    {keep_state_and_data, [postpone]}.

%% ---------------------------------------------------------------------------
%% Effects
%% ---------------------------------------------------------------------------

now(#d{clock = Clock}) -> avatar_sim_clock:now(Clock).

link_of(Entity, #d{links = Links}) ->
    case Links of
        #{Entity := Pid} -> {ok, Entity, Pid};
        #{} -> {error, no_link}
    end.

effects(Effects, Now, D) ->
    lists:foldl(fun(E, Acc) -> effect(E, Now, Acc) end, D, Effects).

effect({answer, #{context := request_no_feedback}, _Context, _Body}, _Now, D) ->
    %% A Request that awaits no feedback is carried out and not answered,
    %% now or when the action ends.
    D;
effect({answer, #{id := Id, sender := To, receiver := From}, Context, Body}, Now, D) ->
    Signal = #{context => Context, sender => From, receiver => To, in_reply_to => Id,
               timestamp => Now, body => Body},
    emit(From, answer, Signal, D);
effect({push, Component, Context, Body}, Now, D) ->
    Signal = #{context => Context, sender => Component, timestamp => Now, body => Body},
    emit(Component, push, Signal, D);
effect({file, Path, Bytes}, _Now, D) ->
    ok = filelib:ensure_dir(Path),
    case file:write_file(Path, Bytes) of
        ok -> ok;
        {error, Why} -> logger:error(#{what => write_failed, file => Path, reason => Why})
    end,
    D.

emit(Component, Kind, #{timestamp := Now, context := Ctx, body := Body} = Signal, D) ->
    Entity = maps:get(Component, D#d.owner, undefined),
    case D#d.links of
        #{Entity := Link} -> avatar_sim_link:emit(Link, Kind, Signal);
        #{} -> ok
    end,
    log(#{time => Now, entity => Entity, component => Component, context => Ctx,
          type => maps:get(type, Body), params => maps:get(parameters, Body)}, D).

log(_Entry, #d{logged = N} = D) when N >= ?MAX_LOG -> D;
log(Entry, #d{log = Log, logged = N} = D) -> D#d{log = [Entry | Log], logged = N + 1}.
