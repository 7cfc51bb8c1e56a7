%% @doc Internal. One MQTT Avatar: an MQTT session (mqtt_client) on one
%% side, an EVATAR session (agent_bridge_client, role avatar) on the other,
%% and mqtt_avatar_logic deciding in between. Discovery messages rebuild
%% the description; a changed description is sent to EVATAR again.
%%
%% ```
%%  starting --MQTT connected, subscribed--> discovering --quiet for `settle' ms
%%     |                                         |          (or `discovery_wait')
%%     | (no discovery)                          v
%%     +-------------------------------------> joining --Welcome, described--> joined
%%                                               ^   | refused / unreachable     |
%%                                               |   v (retry, doubling)         |
%%                                               +---+--------- closed ----------+
%% '''
%% The delay before joining again starts at `retry' and doubles (up to 5 s)
%% with every join that ends before the pairing bound the Avatar: a
%% connect that is then refused (a description over a limit, a join
%% timeout) does not reset it; the first Binding report does. A
%% description longer than the Welcome's MaxFrame is not sent: it is a
%% `description_too_large' problem naming the limit, and the Avatar leaves
%% (joining) or keeps its last accepted description (joined). A problem of
%% joining is reported once, not at every attempt, until the Avatar is
%% bound.
%% MQTT messages are handled in every state; the MQTT client reconnects
%% and resubscribes by itself, and reports `connected'/`disconnected'.
-module(mqtt_avatar_fsm).
-behaviour(gen_statem).

-include_lib("kernel/include/logger.hrl").

-export([start_link/1, start/1]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

%% The states of the machine (the diagram above).
-type state() :: starting | discovering | joining | joined.

-define(MAX_PROBLEMS, 100).
-define(MAX_RETRY, 5000).
%% What the Avatar's bridge client reads: the largest Binding report a
%% pairing can be set to send (max_binding_report, docs/protocol.md
%% section 7), so that no report the pairing allows closes the session.
-define(READ_MAX_FRAME, 268435456).
-define(BIRTH_TOPIC, <<"homeassistant/status">>).
-define(BIRTH_PAYLOAD, <<"online">>).

-record(d, {opts :: mqtt_avatar:opts(),
            entity :: binary(),
            mqtt :: pid() | undefined,
            bridge :: pid() | undefined,
            discovery :: mqtt_avatar_discovery:state() | undefined,
            static :: [bil:component()],
            description :: bil:description(),
            %% the description's runtime spec
            spec = #{components => [], topics => []} :: mqtt_avatar_spec:spec(),
            described :: bil:description() | undefined,
            logic :: mqtt_avatar_logic:state(),
            subscribed = [] :: [binary()],
            mqtt_up = false :: boolean(),
            retry :: pos_integer(),
            %% joins attempted, and the last problem of joining (reported
            %% once until bound)
            joins = 0 :: non_neg_integer(),
            join_problem :: map() | undefined,
            problems = [] :: [map()],
            %% the problems of the last generated description, reported once
            generated = [] :: [map()],
            waiters = [] :: [gen_statem:from()]}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

-spec start_link(mqtt_avatar:opts()) -> {ok, pid()} | {error, term()}.
start_link(Opts) ->
    gen_statem:start_link(?MODULE, Opts, []).

-spec start(mqtt_avatar:opts()) -> {ok, pid()} | {error, term()}.
start(Opts) ->
    gen_statem:start(?MODULE, Opts, []).

%% ---------------------------------------------------------------------------
%% gen_statem
%% ---------------------------------------------------------------------------

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init(mqtt_avatar:opts()) -> gen_statem:init_result(starting).
init(#{entity_id := Entity} = Opts) ->
    logger:set_process_metadata(#{entity => Entity, domain => [mqtt_avatar]}),
    Static = maps:get(static_components, Opts, []),
    Discovery = case maps:get(discovery, Opts, false) of
                    false -> undefined;
                    DOpts -> mqtt_avatar_discovery:new(DOpts)
                end,
    D0 = #d{opts = Opts, entity = Entity, discovery = Discovery, static = Static,
            retry = maps:get(retry, Opts, 200),
            description = #{entity_id => Entity, api_name => <<"MQTT AVATAR">>,
                            entity_type => avatar, context => <<"MqttDescription">>,
                            components => []},
            logic = mqtt_avatar_logic:new(Entity, #{components => [], topics => []},
                                          maps:get(echo_timeout, Opts, 5000),
                                          maps:with([timestamp_field], Opts))},
    {D1, _Changed} = rebuild(D0),
    {ok, starting, D1, [{next_event, internal, start_mqtt}]}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(internal, start_mqtt, starting, #d{opts = Opts, entity = Entity} = D) ->
    MqttOpts0 = maps:get(mqtt, Opts),
    ClientId = maps:get(client_id, MqttOpts0,
                        iolist_to_binary(["evatar-", Entity, "-",
                                          binary:encode_hex(crypto:strong_rand_bytes(3))])),
    MqttOpts = MqttOpts0#{owner => self(), client_id => ClientId,
                          reconnect => maps:get(reconnect, MqttOpts0,
                                                #{min_ms => 100, max_ms => 2000})},
    {ok, Pid} = mqtt_client:start_link(MqttOpts),
    %% The client stops by itself only when the broker refuses it for good
    %% (bad credentials, a refused protocol): then so does the Avatar.
    monitor(process, Pid),
    {keep_state, D#d{mqtt = Pid}};

%% MQTT session events, in every state.
handle_event(info, {mqtt_client, Pid, {connected, _}}, State, #d{mqtt = Pid} = D) ->
    D1 = birth(subscribe(D#d{mqtt_up = true})),
    {D2, Actions} = logic({mqtt_status, up}, D1),
    case State of
        starting when D2#d.discovery =/= undefined ->
            {next_state, discovering, D2,
             [{state_timeout, maps:get(discovery_wait, D2#d.opts, 3000), give_up},
              settle_timer(D2) | Actions]};
        starting ->
            {next_state, joining, D2, [{next_event, internal, join} | Actions]};
        _ ->
            {keep_state, D2, Actions}
    end;
handle_event(info, {mqtt_client, Pid, {disconnected, Reason}}, _State, #d{mqtt = Pid} = D) ->
    ?LOG_NOTICE(#{what => mqtt_disconnected, entity => D#d.entity, reason => Reason}),
    keep(logic({mqtt_status, down}, D#d{mqtt_up = false}));
handle_event(info, {mqtt_client, Pid, {publish, #{topic := Topic, payload := Payload} = Msg}},
             State, #d{mqtt = Pid} = D) ->
    case discovery(Topic, Payload, D) of
        ignore ->
            keep(logic({mqtt, maps:with([topic, payload, retain], Msg)}, D));
        {unchanged, D1} ->
            {keep_state, D1};
        {changed, D1} ->
            %% Wait until the burst of (retained) configs is over.
            case State of
                starting -> {keep_state, D1};
                _ -> {keep_state, D1, [settle_timer(D1)]}
            end
    end;
handle_event(info, {mqtt_client, Pid, {puback, Key}}, _State, #d{mqtt = Pid} = D)
  when Key =/= undefined ->
    keep(logic({puback, Key}, D));
handle_event(info, {mqtt_client, Pid, {puback_error, Key, Reason}}, _State, #d{mqtt = Pid} = D)
  when Key =/= undefined ->
    keep(logic({publish_failed, Key, Reason}, D));
handle_event(info, {mqtt_client, _, _}, _State, _D) ->
    keep_state_and_data;

%% Discovery settles.
handle_event({timeout, settle}, settle, State, D) ->
    {D1, Changed} = rebuild(D),
    D2 = subscribe(D1),
    case State of
        discovering -> {next_state, joining, D2, [{next_event, internal, join}]};
        joined when Changed -> {keep_state, describe(D2)};
        _ -> {keep_state, D2}
    end;
handle_event(state_timeout, give_up, discovering, D) ->
    ?LOG_NOTICE(#{what => discovery_still_busy, entity => D#d.entity,
                  message => <<"joining EVATAR with what is discovered so far">>}),
    {D1, _} = rebuild(D),
    {next_state, joining, subscribe(D1), [{next_event, internal, join}, {{timeout, settle}, cancel}]};

%% EVATAR session.
handle_event(internal, join, joining, #d{opts = Opts} = D) ->
    case maps:get(evatar, Opts, false) of
        false ->
            {next_state, joined, reply_waiters(D)};
        #{endpoints := Endpoints, pairing := Pairing} = E ->
            ClientOpts = #{pairing => Pairing, role => avatar, entity_id => D#d.entity,
                           credential => maps:get(credential, E, <<>>), owner => self(),
                           max_frame => ?READ_MAX_FRAME},
            D0 = D#d{joins = D#d.joins + 1},
            case agent_bridge_client:connect(Endpoints, ClientOpts) of
                {ok, Client} ->
                    monitor(process, Client),
                    case describe(D0#d{bridge = Client, described = undefined}) of
                        #d{bridge = undefined} = D1 ->
                            %% Not described: the description is over a limit.
                            {keep_state, backoff(D1), [{state_timeout, D#d.retry, retry}]};
                        D1 ->
                            ?LOG_INFO(#{what => joined, entity => D#d.entity, pairing => Pairing}),
                            {next_state, joined, reply_waiters(D1)}
                    end;
                {error, Reason} ->
                    D1 = join_problem(#{what => join_failed, pairing => Pairing,
                                        message => join_failure(Reason)}, D0),
                    {keep_state, backoff(D1), [{state_timeout, D#d.retry, retry}]}
            end
    end;
handle_event(state_timeout, retry, joining, _D) ->
    {keep_state_and_data, [{next_event, internal, join}]};
handle_event(info, {agent_bridge, C, {signal, Signal}}, _State, #d{bridge = C} = D) ->
    keep(logic({signal, Signal}, D));
handle_event(info, {agent_bridge, C, {binding, Report}}, _State, #d{bridge = C} = D) ->
    %% Bound: the next loss starts the back-off over.
    keep(logic({binding, Report}, D#d{retry = maps:get(retry, D#d.opts, 200),
                                       join_problem = undefined}));
handle_event(info, {agent_bridge, C, {closed, Reason}}, _State, #d{bridge = C} = D) ->
    {next_state, joining, backoff(lost_bridge(Reason, D)), [{state_timeout, D#d.retry, retry}]};
handle_event(info, {'DOWN', _, process, C, Reason}, _State, #d{bridge = C} = D) ->
    {next_state, joining, backoff(lost_bridge(Reason, D)), [{state_timeout, D#d.retry, retry}]};
handle_event(info, {agent_bridge, _, _}, _State, _D) ->
    keep_state_and_data;
handle_event(info, {'DOWN', _, process, Pid, Reason}, _State, #d{mqtt = Pid} = D) ->
    ?LOG_ERROR(#{what => mqtt_client_stopped, entity => D#d.entity, reason => Reason}),
    {stop, {mqtt_client_stopped, Reason}, D#d{mqtt = undefined}};
handle_event(info, {'DOWN', _, process, _, _}, _State, _D) ->
    keep_state_and_data;

%% Commands waiting for their state echo.
handle_event({timeout, {echo, Key}}, Key, _State, D) ->
    keep(logic({echo_timeout, Key}, D));

%% Inspection.
handle_event({call, From}, description, _State, D) ->
    {keep_state_and_data, [{reply, From, D#d.description}]};
handle_event({call, From}, problems, _State, D) ->
    {keep_state_and_data, [{reply, From, lists:reverse(D#d.problems)}]};
handle_event({call, From}, status, State, D) ->
    L = D#d.logic,
    Status = #{state => State,
               mqtt => case D#d.mqtt_up of true -> up; false -> down end,
               broker => maps:with([host, port], maps:get(mqtt, D#d.opts)),
               evatar => case D#d.bridge of undefined -> down; _ -> up end,
               joins => D#d.joins,
               retry => D#d.retry,
               components => [Id || #{id := Id} <- maps:get(components, D#d.description)],
               availability => mqtt_avatar_logic:availability(L),
               last_values => mqtt_avatar_logic:last_values(L),
               pending => mqtt_avatar_logic:pending_count(L),
               partners => mqtt_avatar_logic:partners(L),
               subscriptions => D#d.subscribed},
    {keep_state_and_data, [{reply, From, Status}]};
handle_event({call, From}, await_ready, joined, _D) ->
    {keep_state_and_data, [{reply, From, ok}]};
handle_event({call, From}, await_ready, _State, D) ->
    {keep_state, D#d{waiters = [From | D#d.waiters]}};
handle_event({call, From}, stop, _State, D) ->
    D1 = case D#d.bridge of
             undefined -> D;
             C -> ok = agent_bridge_client:close(C), D#d{bridge = undefined}
         end,
    {stop_and_reply, normal, [{reply, From, ok}], D1};
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Reason, _State, #d{mqtt = Mqtt}) ->
    case Mqtt of
        undefined -> ok;
        Pid -> _ = mqtt_client:stop(Pid), ok
    end.

%% ---------------------------------------------------------------------------
%% Internals
%% ---------------------------------------------------------------------------

settle_timer(D) ->
    {{timeout, settle}, maps:get(settle, D#d.opts, 500), settle}.

reply_waiters(#d{waiters = W} = D) ->
    _ = [gen_statem:reply(From, ok) || From <- W],
    D#d{waiters = []}.

lost_bridge(Reason, D) ->
    ?LOG_NOTICE(#{what => evatar_link_lost, entity => D#d.entity, reason => Reason}),
    D1 = case Reason of
             {refused, <<"FrameTooLarge">>, Message} ->
                 join_problem(#{what => description_too_large,
                                message => <<"EVATAR closed the session: ", Message/binary,
                                             (raise_frame())/binary>>}, D);
             _ ->
                 D
         end,
    D1#d{bridge = undefined, described = undefined,
         logic = element(1, mqtt_avatar_logic:handle({binding, #{bound => []}}, now_ms(),
                                                     D1#d.logic))}.

%% The next delay before joining again: doubled, until bound.
backoff(#d{retry = R} = D) ->
    D#d{retry = min(?MAX_RETRY, R * 2)}.

join_failure({refused, Code, Message}) ->
    <<"EVATAR refused the join: ", Code/binary, " (", Message/binary, ")">>;
join_failure(Reason) ->
    iolist_to_binary(io_lib:format("~0p", [Reason])).

%% A problem of joining, reported when it differs from the last one since
%% the Avatar was last bound: a join refused for the same reason every few
%% seconds is one problem, not one per attempt.
join_problem(#{code := <<"JoinTimeout">>}, #d{join_problem = Last} = D)
  when Last =/= undefined ->
    %% The pairing's timeout that follows a description not sent or refused.
    D;
join_problem(Report, #d{join_problem = Last} = D) ->
    Key = maps:with([what, code, message], Report),
    case Key =:= Last of
        true -> D;
        false -> problem(Report, D#d{join_problem = Key})
    end.

raise_frame() ->
    <<"; raise the listener's max_frame (conn => #{max_frame => Bytes} in the node "
      "configuration file's listeners entry) and the bil application's max_description_size "
      "(EVATAR_MAX_DESCRIPTION_SIZE), or make the description smaller (overrides with skip); "
      "docs/mqtt.md section 6, Limits">>.

discovery(_Topic, _Payload, #d{discovery = undefined}) ->
    ignore;
discovery(Topic, Payload, #d{discovery = S} = D) ->
    case mqtt_avatar_discovery:handle(Topic, Payload, S) of
        ignore ->
            ignore;
        {Changed, S1, Problems} ->
            D1 = lists:foldl(fun problem/2, D#d{discovery = S1}, Problems),
            {Changed, D1}
    end.

%% Regenerates the description from the static components (checked at
%% start) and what was discovered (checked by mqtt_avatar_generate, which
%% leaves out and reports what it cannot use).
rebuild(#d{opts = Opts, entity = Entity, static = Static} = D) ->
    Devices = case D#d.discovery of
                  undefined -> [];
                  S -> mqtt_avatar_discovery:devices(S)
              end,
    {Full, Spec, Problems} = mqtt_avatar_generate:build(
                               #{entity_id => Entity, static => Static,
                                 overrides => maps:get(overrides, Opts, #{}),
                                 api_name => maps:get(api_name, Opts, <<"MQTT AVATAR">>)},
                               Devices, []),
    %% A problem is reported when it first appears (a device left out
    %% because of its config is reported when the config arrives, even if
    %% the description stays the same), and not again while it lasts.
    Before = sets:from_list(D#d.generated),
    D1 = lists:foldl(fun problem/2, D, [P || P <- Problems, not sets:is_element(P, Before)]),
    Changed = Full =/= D#d.description,
    {D1#d{description = Full, spec = Spec, generated = Problems,
          logic = mqtt_avatar_logic:set_spec(Spec, D1#d.logic)}, Changed}.

%% Sends the description when it changed and fits the session's MaxFrame.
%% One that does not is a problem: before the first description the
%% Avatar leaves (the bridge is undefined on return), after it the pairing
%% keeps the last one sent.
describe(#d{bridge = undefined} = D) ->
    D;
describe(#d{bridge = C, description = Full, described = Old} = D) ->
    Public = mqtt_avatar_spec:public(Full),
    case Public =:= Old of
        true ->
            D;
        false ->
            Doc = bil:encode_description(Public),
            Size = iolist_size(Doc),
            case agent_bridge_client:session(C) of
                {ok, #{max_frame := Max}} when Size > Max ->
                    too_large(Size, Max, D);
                _ ->
                    case agent_bridge_client:describe_document(C, Doc) of
                        ok -> D#d{described = Public};
                        {error, closed} -> D
                    end
            end
    end.

too_large(Size, Max, #d{bridge = C, described = Old} = D) ->
    N = length(maps:get(components, D#d.description)),
    Kept = case Old of
               undefined -> <<"not joined">>;
               _ -> <<"the Avatar runs on its last accepted description">>
           end,
    Message = iolist_to_binary(
                io_lib:format("the description (~b components) is ~b bytes, over the ~b bytes of "
                              "EVATAR's max_frame: ~ts~ts",
                              [N, Size, Max, Kept, raise_frame()])),
    D1 = join_problem(#{what => description_too_large, size => Size, max_frame => Max,
                        message => Message}, D),
    case Old of
        undefined ->
            ok = agent_bridge_client:close(C),
            D1#d{bridge = undefined};
        _ ->
            D1
    end.

subscribe(#d{mqtt_up = false} = D) ->
    D;
subscribe(#d{mqtt = Pid, subscribed = Done, spec = Spec} = D) ->
    Wanted = lists:usort(discovery_filters(D) ++ maps:get(topics, Spec)),
    case ordsets:subtract(Wanted, Done) of
        [] ->
            D;
        New ->
            case mqtt_client:subscribe(Pid, [{T, 1} || T <- New], 5000) of
                {ok, _Codes} ->
                    D#d{subscribed = ordsets:union(Done, New)};
                {error, Reason} ->
                    problem(#{what => subscribe_failed,
                              message => iolist_to_binary(io_lib:format("~0p", [Reason]))}, D)
            end
    end.

%% Home Assistant's birth message, after every (re)connection and once
%% subscribed: devices that announce themselves (configs, states) only when
%% Home Assistant comes online then announce themselves to us too.
birth(#d{opts = Opts, mqtt = Pid} = D) ->
    case maps:get(birth, Opts, #{}) of
        false ->
            D;
        Birth ->
            Topic = maps:get(topic, Birth, ?BIRTH_TOPIC),
            Payload = maps:get(payload, Birth, ?BIRTH_PAYLOAD),
            ok = mqtt_client:publish_async(Pid, Topic, Payload, #{qos => 1}),
            D
    end.

discovery_filters(#d{discovery = undefined}) -> [];
discovery_filters(#d{discovery = S}) -> mqtt_avatar_discovery:subscriptions(S).

keep({D, Actions}) ->
    {keep_state, D, Actions}.

%% Runs the pure logic and carries out its effects; timers become
%% gen_statem actions.
logic(Event, #d{logic = L} = D) ->
    {L1, Effects} = mqtt_avatar_logic:handle(Event, now_ms(), L),
    lists:foldl(fun effect/2, {D#d{logic = L1}, []}, Effects).

effect({send, Signal}, {#d{bridge = undefined}, _} = Acc) ->
    ?LOG_DEBUG(#{what => signal_dropped, reason => not_joined, signal => Signal}),
    Acc;
effect({send, Signal}, {#d{bridge = C}, _} = Acc) ->
    _ = agent_bridge_client:send(C, Signal),
    Acc;
effect({publish, Topic, Payload, Key}, {#d{mqtt = Pid}, _} = Acc) ->
    Opts = case Key of
               undefined -> #{qos => 1};
               _ -> #{qos => 1, ref => Key}
           end,
    ok = mqtt_client:publish_async(Pid, Topic, Payload, Opts),
    Acc;
effect({start_timer, Key, Ms}, {D, Actions}) ->
    {D, Actions ++ [{{timeout, {echo, Key}}, Ms, Key}]};
effect({cancel_timer, Key}, {D, Actions}) ->
    {D, Actions ++ [{{timeout, {echo, Key}}, cancel}]};
effect({problem, #{what := evatar_error, code := Code} = Report}, {D, Actions})
  when Code =:= <<"DescriptionRefused">>; Code =:= <<"JoinTimeout">> ->
    {join_problem(Report, D), Actions};
effect({problem, Report}, {D, Actions}) ->
    {problem(Report, D), Actions}.

problem(Report, #d{problems = Ps, entity = E} = D) ->
    R = Report#{time => os:system_time(millisecond)},
    ?LOG_WARNING(R#{entity => E}),
    D#d{problems = lists:sublist([R | Ps], ?MAX_PROBLEMS)}.

now_ms() -> erlang:monotonic_time(millisecond).
