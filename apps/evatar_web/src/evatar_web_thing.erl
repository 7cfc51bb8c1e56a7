%% @doc Internal. The WoT consumer of one pairing (http option `things',
%% docs/wot.md): joins the pairing as its agent with its own EntityID and
%% credential, like any VA, and registers the counterpart of the Avatars'
%% descriptions (evatar_web_td:counterpart/2), so that binding pairs it
%% with every Avatar component. An invoked TD action is a
%% RequestAwaitingFeedback from its stand-in component; the Feedback (or
%% EVATAR's Timeout) is the caller's answer. SensorData (or an Event) kept,
%% last per stream, is what a property read returns.
%%
%% ```
%%  joining --ok--> joined --dropped/pairing down--> joining
%%     \--refused (occupied, unknown_pairing, ...)--> retry in 2 s
%% '''
%% A pairing holds one agent: while a VA is joined the consumer is refused
%% `occupied', and while the consumer is joined a VA is.
-module(evatar_web_thing).
-behaviour(gen_server).

-include_lib("kernel/include/logger.hrl").

-export([start_link/1, status/1, things/1, invoke/5, read/4]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-define(RETRY_MS, 2000).

-type config() :: #{pairing := binary(), credential := binary(), entity_id := binary()}.
-export_type([config/0]).

-spec start_link(config()) -> {ok, pid()}.
start_link(Config) ->
    gen_server:start_link(?MODULE, Config, []).

%% @doc `joined', or `{refused, Reason}' while it cannot join.
-spec status(pid()) -> joined | {refused, atom()}.
status(Pid) -> gen_server:call(Pid, status, 5000).

%% @doc The Avatar descriptions it pairs with, as last read.
-spec things(pid()) -> [bil:description()].
things(Pid) -> gen_server:call(Pid, things, 5000).

%% @doc Invokes service `Type' of `Component' of Avatar `Entity' with
%% `Params' over the described ones: `{ok, Feedback}' or `{error, Why}'.
-spec invoke(pid(), binary(), binary(), binary(), [{binary(), binary()}]) ->
          {ok, bil:signal()} | {error, term()}.
invoke(Pid, Entity, Component, Type, Params) ->
    Timeout = maps:get(feedback_timeout, gen_server:call(Pid, options, 5000), 5000),
    try gen_server:call(Pid, {invoke, Entity, Component, Type, Params}, Timeout + 10000)
    catch exit:{timeout, _} -> {error, no_answer}
    end.

%% @doc The last reading of a sensor stream: `{ok, Signal}' or `{error, Why}'.
-spec read(pid(), binary(), binary(), binary()) -> {ok, bil:signal()} | {error, term()}.
read(Pid, Entity, Component, Type) ->
    gen_server:call(Pid, {read, Entity, Component, Type}, 5000).

%% ---------------------------------------------------------------------------

%% @private
init(#{pairing := P, entity_id := E} = Config) ->
    logger:set_process_metadata(#{pairing => P, entity => E}),
    self() ! join,
    {ok, #{config => Config, session => undefined, status => {refused, not_yet},
           avatars => [], pending => #{}, readings => #{}, n => 0, options => #{}}}.

%% @private
handle_call(status, _From, #{status := S} = St) ->
    {reply, S, St};
handle_call(things, _From, #{avatars := A} = St) ->
    {reply, A, St};
handle_call(options, _From, #{options := O} = St) ->
    {reply, O, St};
handle_call({invoke, _, _, _, _}, _From, #{session := undefined, status := S} = St) ->
    {reply, {error, {not_joined, S}}, St};
handle_call({invoke, Entity, Comp, Type, Params}, From, St) ->
    case find(Entity, Comp, services, Type, St) of
        {ok, #{category := Cat, type := T, parameters := Described}} ->
            N = maps:get(n, St) + 1,
            Id = <<"wot-", (integer_to_binary(N))/binary>>,
            Given = maps:from_list(Params),
            Ps = [{K, maps:get(K, Given, V)} || {K, V} <- Described],
            Signal = #{id => Id, context => request,
                       sender => evatar_web_td:component_id(Comp), receiver => Comp,
                       in_reply_to => undefined, timestamp => erlang:system_time(millisecond),
                       seq => undefined, epoch => undefined,
                       body => #{category => Cat, type => T, parameters => Ps}},
            ok = evatar:send(maps:get(session, St), Signal),
            {noreply, St#{n := N, pending := (maps:get(pending, St))#{Id => From}}};
        error ->
            {reply, {error, no_such_action}, St}
    end;
handle_call({read, Entity, Comp, Type}, _From, #{readings := R} = St) ->
    case find(Entity, Comp, consumes, Type, St) of
        {ok, #{type := T}} ->
            case maps:find({Comp, bil:keyword(T)}, R) of
                {ok, Signal} -> {reply, {ok, Signal}, St};
                error -> {reply, {error, no_reading}, St}
            end;
        error ->
            {reply, {error, no_such_property}, St}
    end.

%% @private
handle_cast(_, St) ->
    {noreply, St}.

%% @private
handle_info(join, #{session := S} = St) when S =/= undefined ->
    %% A second retry timer (dropped, then the pairing's DOWN): joined already.
    {noreply, St};
handle_info(join, #{config := #{pairing := P, entity_id := E, credential := C}} = St) ->
    case evatar:join(P, agent, E, C) of
        {ok, Session} ->
            Ref = erlang:monitor(process, evatar:session_pid(Session)),
            Options = case evatar:stored_options(P) of
                          {ok, O} -> O;
                          {error, _} -> #{}
                      end,
            ?LOG_NOTICE(#{what => wot_consumer_joined, pairing => P, entity => E}),
            {noreply, describe(St#{session := Session, status := joined, options := Options,
                                   monitor => Ref})};
        {error, Why} ->
            case maps:get(status, St) of
                {refused, Why} -> ok;
                _ -> ?LOG_NOTICE(#{what => wot_consumer_refused, pairing => P, entity => E,
                                   reason => Why, retry_ms => ?RETRY_MS})
            end,
            _ = erlang:send_after(?RETRY_MS, self(), join),
            %% The TDs stay listed while it cannot join; their operations
            %% answer 503 not_joined with the reason.
            {noreply, refresh(St#{status := {refused, reason(Why)}})}
    end;
handle_info({evatar, P, {bound, _Report}}, #{config := #{pairing := P}} = St) ->
    {noreply, describe(St)};
handle_info({evatar, P, {signal, #{in_reply_to := R} = Signal}},
            #{config := #{pairing := P}, pending := Pending} = St) when is_map_key(R, Pending) ->
    case Signal of
        #{context := progress} ->
            {noreply, St};
        _ ->
            gen_server:reply(maps:get(R, Pending), {ok, Signal}),
            {noreply, St#{pending := maps:remove(R, Pending)}}
    end;
handle_info({evatar, P, {signal, #{context := Ctx, sender := From,
                                   body := #{type := T}} = Signal}},
            #{config := #{pairing := P}, readings := R} = St)
  when Ctx =:= sensor_data; Ctx =:= event ->
    %% A stream pushed as SensorData or as Event (the microphone's).
    {noreply, St#{readings := R#{{From, bil:keyword(T)} => Signal}}};
handle_info({evatar, P, {signal, _}}, #{config := #{pairing := P}} = St) ->
    {noreply, St};
handle_info({evatar, P, {dropped, Code, _Why}}, #{config := #{pairing := P}} = St) ->
    {noreply, gone(Code, St)};
handle_info({'DOWN', Ref, process, _, _}, #{monitor := Ref, session := S} = St) when S =/= undefined ->
    {noreply, gone(pairing_down, St)};
handle_info(_, St) ->
    {noreply, St}.

gone(Why, #{pending := Pending} = St) ->
    _ = [gen_server:reply(F, {error, {not_joined, {refused, Why}}}) || F <- maps:values(Pending)],
    _ = case St of
            #{monitor := Ref} -> erlang:demonitor(Ref, [flush]);
            #{} -> true
        end,
    _ = erlang:send_after(?RETRY_MS, self(), join),
    St#{session := undefined, status := {refused, Why}, pending := #{}, described => false,
        monitor => undefined}.

reason(W) when is_atom(W) -> W;
reason({not_active, _}) -> not_active.

%% Reads the pairing's registration list and registers the counterpart of
%% its Avatars when it changed (a registration rebinds and reports again:
%% the second read finds nothing new).
describe(#{session := undefined} = St) ->
    St;
describe(#{config := #{pairing := P, entity_id := E}, session := S} = St) ->
    case evatar:registry(P) of
        {ok, List} ->
            Avatars = [D || #{role := avatar, description := D} <- List, D =/= undefined],
            case Avatars =:= maps:get(avatars, St) andalso maps:get(described, St, false) of
                true ->
                    St;
                false ->
                    case evatar:describe(S, evatar_web_td:counterpart(E, Avatars)) of
                        ok -> ok;
                        {error, Why} ->
                            ?LOG_WARNING(#{what => wot_describe_refused, pairing => P, reason => Why})
                    end,
                    St#{avatars := Avatars, described => true}
            end;
        {error, _} ->
            St
    end.

refresh(#{config := #{pairing := P}} = St) ->
    case evatar:registry(P) of
        {ok, List} -> St#{avatars := [D || #{role := avatar, description := D} <- List, D =/= undefined]};
        {error, _} -> St#{avatars := []}
    end.

find(Entity, Comp, Side, Type, #{avatars := Avatars}) ->
    K = bil:keyword(Type),
    case [E || #{entity_id := En, components := Cs} <- Avatars, En =:= Entity,
               #{id := Id} = C <- Cs, Id =:= Comp,
               #{type := T} = E <- maps:get(Side, C), bil:keyword(T) =:= K] of
        [E | _] -> {ok, E};
        [] -> error
    end.
