%% @doc Internal. One WoT Avatar: fetches its Thing's TD (HTTP GET with
%% httpc, or a file), describes it (wot_avatar:describe/2), joins the
%% pairing as role `avatar' with agent_bridge_client, and carries the VA's
%% requests to the Thing's forms and the Thing's readings and events back
%% (wot_avatar_route decides, this process does the I/O). Its own httpc
%% (stand-alone, so a Thing's long-polls never wait behind another's), and
%% for MQTT forms one mqtt_client per broker, started when it joins: a
%% publish (QoS 1) carries a request, answered when the broker's PUBACK
%% comes (the Thing answers nothing over MQTT); each message on a
%% subscribed topic is a reading of its streams. The broker's connection
%% lost is the Thing gone.
%%
%% ```
%%  fetching --TD read, described, joined--> joined
%%     ^  |                                    | the Thing unreachable (connect refused,
%%     |  | TD unreachable, refused,           | connection closed): pending requests
%%     |  v join refused                       v answered DeviceUnavailable, Bye
%%     +-- away <------------------------------+ EVATAR's connection lost
%%   (retry after a delay doubling from 500 ms to retry_max_ms)
%% '''
%% A request's timeout or HTTP error status is its Error answer, never a
%% crash, and does not make the Thing away.
-module(wot_avatar_fsm).
-behaviour(gen_statem).

-include_lib("kernel/include/logger.hrl").

-export([start_link/1]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-define(MAX_PROBLEMS, 100).
-define(MIN_RETRY, 500).

-type state() :: fetching | away | joined.
%% What an HTTP request in flight is for: the TD, a VA's request, or the
%% stream with that index (its SSE buffer).
-type purpose() :: td | {request, wot_avatar_route:pending()} | {stream, pos_integer()}
                 | {sse, pos_integer(), binary()} | {mqtt, wot_avatar_route:pending()}.

-record(d, {opts :: wot_avatar:opts(),
            entity :: binary(),
            httpc :: pid(),
            description :: bil:description() | undefined,
            routes :: wot_avatar_generate:routes() | undefined,
            streams = #{} :: #{pos_integer() => wot_avatar_generate:stream()},
            td_problems = [] :: [wot_avatar:problem()],
            problems = [] :: [map()],
            bridge :: pid() | undefined,
            bound = [] :: [bil:binding()],
            inflight = #{} :: #{term() => purpose()},
            %% MQTT: a client per broker, the streams of each topic
            brokers = #{} :: #{{binary(), inet:port_number()} => pid()},
            topics = #{} :: #{binary() => [pos_integer()]},
            last = #{} :: #{pos_integer() => [bil:parameter()]},
            retry = ?MIN_RETRY :: pos_integer(),
            %% the reason of the last problem of each kind, reported once while it lasts
            quiet = #{} :: #{atom() => term()},
            waiters = [] :: [gen_statem:from()]}).

-spec start_link(wot_avatar:opts()) -> {ok, pid()} | {error, term()}.
start_link(Opts) ->
    gen_statem:start_link(?MODULE, Opts, []).

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init(wot_avatar:opts()) -> gen_statem:init_result(state()).
init(#{entity_id := Entity} = Opts) ->
    process_flag(trap_exit, true),
    logger:set_process_metadata(#{entity => Entity, domain => [wot_avatar]}),
    {ok, Httpc} = inets:start(httpc, [{profile, wot_avatar}], stand_alone),
    ok = httpc:set_options([{max_sessions, 64}, {max_keep_alive_length, 0}, {keep_alive_timeout, 0},
                            {max_pipeline_length, 0}], Httpc),
    {ok, fetching, #d{opts = Opts, entity = Entity, httpc = Httpc}, [{next_event, internal, fetch}]}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(internal, fetch, fetching, #d{opts = #{td := {file, File}}} = D) ->
    case file:read_file(File) of
        {ok, Text} -> got_td(Text, D);
        {error, R} -> away(td_unreachable, iolist_to_binary([File, ": ", file:format_error(R)]), D)
    end;
handle_event(internal, fetch, fetching, #d{opts = #{td := Url} = Opts} = D) ->
    Http = #{method => <<"GET">>, url => Url, headers => [{"accept", "application/td+json, application/json"}],
             content_type => <<"application/json">>, body => none},
    {keep_state, issue(Http, timeout(Opts), [], td, D)};
handle_event(state_timeout, retry, away, D) ->
    {next_state, fetching, D, [{next_event, internal, fetch}]};

%% HTTP answers.
handle_event(info, {http, {Ref, Result}}, State, #d{inflight = In} = D) when is_map_key(Ref, In) ->
    http_done(maps:get(Ref, In), Result, State, D#d{inflight = maps:remove(Ref, In)});
handle_event(info, {http, {Ref, stream_start, _Headers}}, _State, _D) when is_reference(Ref) ->
    keep_state_and_data;
handle_event(info, {http, {Ref, stream, Part}}, joined, #d{inflight = In} = D) when is_map_key(Ref, In) ->
    {sse, N, Buf} = maps:get(Ref, In),
    Max = max_body(D#d.opts),
    case wot_avatar_route:sse(<<Buf/binary, Part/binary>>, Max) of
        too_large ->
            _ = httpc:cancel_request(Ref, D#d.httpc),
            D1 = problem(#{what => stream_too_large, stream => stream_type(N, D),
                           message => <<"an event of the SSE stream is over max_body; subscribing again">>},
                         D#d{inflight = maps:remove(Ref, In)}),
            {keep_state, D1, [{{timeout, {stream, N}}, D#d.retry, again}]};
        {Datas, Rest} ->
            D1 = lists:foldl(fun(Data, DAcc) -> push(N, Data, DAcc) end,
                             D#d{inflight = In#{Ref => {sse, N, Rest}}}, Datas),
            {keep_state, D1}
    end;
handle_event(info, {http, {Ref, stream_end, _Headers}}, joined, #d{inflight = In} = D)
  when is_map_key(Ref, In) ->
    {sse, N, _} = maps:get(Ref, In),
    {keep_state, open_stream(N, D#d{inflight = maps:remove(Ref, In)})};
handle_event(info, {http, _}, _State, _D) ->
    %% a request cancelled when the Thing went away
    keep_state_and_data;
handle_event({timeout, {stream, N}}, again, joined, D) ->
    {keep_state, open_stream(N, D)};
handle_event({timeout, {stream, _}}, again, _State, _D) ->
    keep_state_and_data;

%% MQTT.
handle_event(info, {mqtt_client, B, {publish, #{topic := Topic, payload := Payload}}}, joined, D) ->
    case lists:member(B, maps:values(D#d.brokers)) of
        true -> {keep_state, lists:foldl(fun(N, DAcc) -> push(N, Payload, DAcc) end, D,
                                         maps:get(Topic, D#d.topics, []))};
        false -> keep_state_and_data
    end;
handle_event(info, {mqtt_client, _B, {puback, Ref}}, joined, #d{inflight = In} = D) when is_map_key(Ref, In) ->
    {mqtt, P} = maps:get(Ref, In),
    {keep_state, send(wot_avatar_route:answer(P, <<>>, ctx(D)), D#d{inflight = maps:remove(Ref, In)}),
     [{{timeout, {mqtt, Ref}}, cancel}]};
handle_event(info, {mqtt_client, _B, {puback_error, Ref, Why}}, joined, #d{inflight = In} = D)
  when is_map_key(Ref, In) ->
    {mqtt, P} = maps:get(Ref, In),
    {keep_state, send(wot_avatar_route:failure(P, {status, 500, text(Why)}, ctx(D)),
                      D#d{inflight = maps:remove(Ref, In)}),
     [{{timeout, {mqtt, Ref}}, cancel}]};
handle_event({timeout, {mqtt, Ref}}, _, joined, #d{inflight = In} = D) when is_map_key(Ref, In) ->
    {mqtt, P} = maps:get(Ref, In),
    {keep_state, send(wot_avatar_route:failure(P, timeout, ctx(D)), D#d{inflight = maps:remove(Ref, In)})};
handle_event({timeout, {mqtt, _}}, _, _State, _D) ->
    keep_state_and_data;
handle_event(info, {mqtt_client, B, {disconnected, Why}}, joined, D) ->
    case lists:member(B, maps:values(D#d.brokers)) of
        true -> gone(<<"the MQTT broker's connection was lost: ", (text(Why))/binary>>, D);
        false -> keep_state_and_data
    end;
handle_event(info, {mqtt_client, _, _}, _State, _D) ->
    keep_state_and_data;

%% EVATAR.
handle_event(info, {agent_bridge, C, {signal, #{context := Ctx} = Signal}}, joined,
             #d{bridge = C, routes = Routes, opts = Opts} = D)
  when Ctx =:= request; Ctx =:= request_no_feedback ->
    case wot_avatar_route:request(Signal, Routes, maps:with([room, thing_credentials], Opts)) of
        {answer, Signals} ->
            {keep_state, send(Signals, D)};
        {http, #{method := <<"PUBLISH">>} = Http, Pending} ->
            publish(Http, Pending, D);
        {http, Http, Pending} ->
            {keep_state, issue(Http, timeout(Opts), [], {request, Pending}, D)};
        {last, Type, Pending} ->
            Last = case [N || {N, #{type := T}} <- maps:to_list(D#d.streams), T =:= Type] of
                       [N] -> maps:get(N, D#d.last, none);
                       [] -> none
                   end,
            {keep_state, send(wot_avatar_route:last(Pending, Last, ctx(D)), D)}
    end;
handle_event(info, {agent_bridge, C, {signal, #{context := error, body := #{type := Code, parameters := Ps}}}},
             _State, #d{bridge = C} = D) ->
    {keep_state, problem(#{what => evatar_error, code => Code,
                           message => proplists:get_value(<<"Message">>, Ps, <<>>)}, D)};
handle_event(info, {agent_bridge, C, {binding, #{bound := Bound}}}, _State, #d{bridge = C} = D) ->
    {keep_state, rebound(Bound, D)};
handle_event(info, {agent_bridge, C, {closed, Reason}}, _State, #d{bridge = C} = D) ->
    lost_bridge(Reason, D);
handle_event(info, {'DOWN', _, process, C, Reason}, _State, #d{bridge = C} = D) ->
    lost_bridge(Reason, D);
handle_event(info, {agent_bridge, _, _}, _State, _D) ->
    keep_state_and_data;

%% Inspection.
handle_event({call, From}, problems, _State, D) ->
    {keep_state_and_data, [{reply, From, D#d.td_problems ++ lists:reverse(D#d.problems)}]};
handle_event({call, From}, description, _State, D) ->
    {keep_state_and_data, [{reply, From, D#d.description}]};
handle_event({call, From}, status, State, D) ->
    Status = #{state => State, entity_id => D#d.entity,
               td => case maps:get(td, D#d.opts) of
                         {file, F} -> unicode:characters_to_binary(F);
                         Url -> Url
                     end,
               thing => case State of joined -> up; _ -> down end,
               evatar => case D#d.bridge of undefined -> down; _ -> up end,
               component => case D#d.routes of undefined -> undefined; #{component := C} -> C end,
               streams => map_size(D#d.streams),
               partners => partners(D),
               pending => length([x || {request, _} <- maps:values(D#d.inflight)]),
               last_values => D#d.last},
    {keep_state_and_data, [{reply, From, Status}]};
handle_event({call, From}, await_ready, joined, _D) ->
    {keep_state_and_data, [{reply, From, ok}]};
handle_event({call, From}, await_ready, _State, D) ->
    {keep_state, D#d{waiters = [From | D#d.waiters]}};
handle_event({call, From}, stop, _State, D) ->
    {stop_and_reply, normal, [{reply, From, ok}], leave(D)};
handle_event(info, {'EXIT', _, normal}, _State, _D) ->
    keep_state_and_data;
handle_event(info, {'EXIT', Pid, Reason}, _State, #d{httpc = Pid} = D) ->
    {stop, {httpc_stopped, Reason}, D};
handle_event(info, {'EXIT', _, _}, _State, _D) ->
    %% the bridge client's exit: its 'DOWN' is handled
    keep_state_and_data;
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Reason, _State, #d{httpc = Httpc} = D) ->
    _ = leave(D),
    _ = inets:stop(stand_alone, Httpc),
    ok.

%% ---------------------------------------------------------------------------
%% The TD, joining, leaving
%% ---------------------------------------------------------------------------

got_td(Text, #d{opts = Opts, entity = Entity} = D) ->
    Describe = maps:merge(maps:with([component, room, api_name, poll_ms, allowed_hosts, max_size,
                                     max_affordances], Opts),
                          #{entity_id => Entity}),
    Source = case maps:get(td, Opts) of
                 {file, _} -> #{};
                 Url -> #{source_url => Url}
             end,
    case wot_avatar:describe(Text, maps:merge(Describe, Source)) of
        {ok, Description, Routes, Problems} ->
            D1 = D#d{td_problems = Problems, description = Description, routes = Routes,
                     streams = maps:from_list(lists:zip(lists:seq(1, length(maps:get(streams, Routes))),
                                                        maps:get(streams, Routes)))},
            join(D1);
        {error, Problems} ->
            away(td_refused, <<"the TD cannot be embodied (GET .../problems lists why)">>,
                 D#d{td_problems = Problems})
    end.

join(#d{opts = #{evatar := #{endpoints := Endpoints, pairing := Pairing} = E}, entity = Entity} = D) ->
    ClientOpts = #{pairing => Pairing, role => avatar, entity_id => Entity,
                   credential => maps:get(credential, E, <<>>), owner => self()},
    case agent_bridge_client:connect(Endpoints, ClientOpts) of
        {ok, Client} ->
            monitor(process, Client),
            _ = agent_bridge_client:describe(Client, D#d.description),
            ?LOG_INFO(#{what => joined, entity => Entity, pairing => Pairing}),
            case brokers(D#d{bridge = Client, bound = [], retry = ?MIN_RETRY, quiet = #{}}) of
                {ok, D0} ->
                    D1 = lists:foldl(fun open_stream/2, D0, maps:keys(D0#d.streams)),
                    _ = [gen_statem:reply(W, ok) || W <- D1#d.waiters],
                    {next_state, joined, D1#d{waiters = []}};
                {error, Why, D0} ->
                    away(thing_gone, <<"the MQTT broker cannot be reached (", Why/binary, ")">>, D0)
            end;
        {error, Reason} ->
            away(join_failed, text(Reason), D)
    end.

%% Away: nothing in flight, not joined; fetch again after the delay.
away(What, Message, #d{opts = Opts} = D) ->
    D1 = leave(D),
    D2 = case maps:get(What, D1#d.quiet, undefined) of
             Message -> D1;
             _ -> problem(#{what => What, message => Message}, D1#d{quiet = #{What => Message}})
         end,
    Delay = D2#d.retry,
    {next_state, away, D2#d{retry = min(maps:get(retry_max_ms, Opts, 30000), Delay * 2)},
     [{state_timeout, Delay, retry}]}.

%% The Thing went away while joined: every request in flight answered,
%% then Bye.
gone(Why, D) ->
    Errors = lists:append([wot_avatar_route:failure(P, {gone, Why}, ctx(D))
                           || {request, P} <- maps:values(D#d.inflight)]),
    away(thing_gone, <<"the Thing cannot be reached (", Why/binary, "): the Avatar left the pairing "
                       "until the Thing answers again">>, send(Errors, D)).

lost_bridge(Reason, D) ->
    ?LOG_NOTICE(#{what => evatar_link_lost, entity => D#d.entity, reason => Reason}),
    away(evatar_link_lost, text(Reason), D#d{bridge = undefined}).

leave(#d{httpc = Httpc, inflight = In, bridge = C} = D) ->
    _ = [httpc:cancel_request(Ref, Httpc) || {Ref, P} <- maps:to_list(In), element(1, P) =/= mqtt],
    _ = [mqtt_client:stop(B) || B <- maps:values(D#d.brokers)],
    case C of
        undefined -> ok;
        _ -> ok = agent_bridge_client:close(C)
    end,
    D#d{inflight = #{}, bridge = undefined, bound = [], brokers = #{}, topics = #{}}.

%% ---------------------------------------------------------------------------
%% MQTT
%% ---------------------------------------------------------------------------

%% A client for each broker the MQTT forms name, connected, with the
%% streams' topics subscribed (QoS 1).
brokers(#d{streams = Streams, routes = #{services := Services}} = D) ->
    Forms = [F || #{form := F} <- maps:values(Streams) ++ maps:values(Services)],
    Hrefs = lists:usort([broker(H) || #{href := <<"mqtt:", _/binary>> = H} <- Forms]),
    Topics = lists:foldl(fun({N, #{mode := mqtt, form := #{href := H}}}, Acc) ->
                                 T = topic(H),
                                 Acc#{T => maps:get(T, Acc, []) ++ [N]};
                            (_, Acc) -> Acc
                         end, #{}, lists:sort(maps:to_list(Streams))),
    connect_brokers(Hrefs, D#d{topics = Topics}).

connect_brokers([], D) ->
    {ok, D};
connect_brokers([{Host, Port} = B | Rest], #d{opts = Opts, entity = E} = D) ->
    Id = iolist_to_binary(["evatar-wot-", E, "-", integer_to_binary(erlang:unique_integer([positive]))]),
    {ok, C} = mqtt_client:start_link(#{host => binary_to_list(Host), port => Port, client_id => Id,
                                       reconnect => false, connect_timeout => timeout(Opts)}),
    D1 = D#d{brokers = (D#d.brokers)#{B => C}},
    Mine = [T || {T, _} <- maps:to_list(D#d.topics), broker_of_topic(T, B, D)],
    case mqtt_client:await_connected(C, timeout(Opts)) of
        ok when Mine =:= [] ->
            connect_brokers(Rest, D1);
        ok ->
            case mqtt_client:subscribe(C, [{T, 1} || T <- Mine], timeout(Opts)) of
                {ok, _} -> connect_brokers(Rest, D1);
                {error, Why} -> {error, text(Why), D1}
            end;
        {error, Why} ->
            {error, text(Why), D1}
    end.

%% The topics map keys topics only: which broker a topic's stream is on.
broker_of_topic(T, B, #d{streams = Streams}) ->
    lists:any(fun(#{mode := mqtt, form := #{href := H}}) -> topic(H) =:= T andalso broker(H) =:= B;
                 (_) -> false
              end, maps:values(Streams)).

broker(Href) ->
    #{host := H} = U = uri_string:parse(Href),
    {string:lowercase(H), maps:get(port, U, 1883)}.

topic(Href) ->
    #{path := <<"/", T/binary>>} = uri_string:parse(Href),
    uri_string:percent_decode(T).

%% A VA's request over MQTT: published with QoS 1, answered at the PUBACK.
publish(#{url := Href, body := Body}, Pending, #d{opts = Opts, inflight = In} = D) ->
    C = maps:get(broker(Href), D#d.brokers),
    Ref = make_ref(),
    ok = mqtt_client:publish_async(C, topic(Href), case Body of none -> <<>>; B -> B end,
                                   #{qos => 1, ref => Ref}),
    {keep_state, D#d{inflight = In#{Ref => {mqtt, Pending}}}, [{{timeout, {mqtt, Ref}}, timeout(Opts), fire}]}.

%% ---------------------------------------------------------------------------
%% HTTP
%% ---------------------------------------------------------------------------

issue(#{method := M, url := Url, headers := Hs, content_type := CT, body := Body}, Timeout, Extra,
      Purpose, #d{httpc = Httpc, inflight = In} = D) ->
    U = unicode:characters_to_list(Url),
    Method = method(M),
    Req = case {Body, Method} of
              {none, get} -> {U, Hs};
              {none, delete} -> {U, Hs};
              {none, _} -> {U, Hs, binary_to_list(CT), <<>>};
              {B, _} -> {U, Hs, binary_to_list(CT), B}
          end,
    {ok, Ref} = httpc:request(Method, Req, [{timeout, Timeout}, {connect_timeout, Timeout},
                                            {autoredirect, false}],
                              [{sync, false}, {body_format, binary} | Extra], Httpc),
    D#d{inflight = In#{Ref => Purpose}}.

method(<<"GET">>) -> get;
method(<<"PUT">>) -> put;
method(<<"POST">>) -> post;
method(<<"DELETE">>) -> delete.

%% What an HTTP result is (as httpc sends it to an asynchronous request's
%% caller): a 2xx body, or why not.
outcome({{_, S, _}, _Hs, Body}, Max) when S >= 200, S < 300 ->
    case byte_size(Body) > Max of
        true -> too_large;
        false -> {ok, Body}
    end;
outcome({{_, S, _}, _Hs, Body}, _Max) ->
    {status, S, Body};
outcome({error, timeout}, _Max) ->
    timeout;
outcome({error, Reason}, _Max) ->
    {gone, text(Reason)}.

http_done(td, Result, fetching, D) ->
    case outcome(Result, min(maps:get(max_size, D#d.opts, maps:get(max_size, wot_avatar:limits())),
                             maps:get(size_limit, wot_avatar:limits()))) of
        {ok, Text} -> got_td(Text, D);
        too_large ->
            P = #{what => too_large, message => <<"the TD fetched is over max_size">>},
            away(td_refused, <<"the TD cannot be embodied (GET .../problems lists why)">>,
                 D#d{td_problems = [P]});
        timeout -> away(td_unreachable, <<"GET of the TD timed out">>, D);
        {status, S, _} -> away(td_unreachable, <<"GET of the TD answered HTTP ", (integer_to_binary(S))/binary>>, D);
        {gone, Why} -> away(td_unreachable, Why, D)
    end;
http_done({request, P}, Result, joined, D) ->
    case outcome(Result, max_body(D#d.opts)) of
        {ok, Body} -> {keep_state, send(wot_avatar_route:answer(P, Body, ctx(D)), D)};
        {gone, Why} -> gone(Why, D);
        Other -> {keep_state, send(wot_avatar_route:failure(P, Other, ctx(D)), D)}
    end;
http_done({stream, N}, Result, joined, D) ->
    #{mode := Mode} = maps:get(N, D#d.streams),
    case {outcome(Result, max_body(D#d.opts)), Mode} of
        {{ok, Body}, {poll, Ms}} ->
            {keep_state, push(N, Body, D), [{{timeout, {stream, N}}, Ms, again}]};
        {{ok, Body}, _} ->
            {keep_state, open_stream(N, push(N, Body, D))};
        {timeout, longpoll} ->
            %% Nothing happened within the long-poll's time: ask again.
            {keep_state, open_stream(N, D)};
        {{gone, Why}, _} ->
            gone(Why, D);
        {Other, _} ->
            D1 = problem(#{what => stream_failed, stream => stream_type(N, D),
                           message => stream_message(Other)}, D),
            Delay = case Mode of
                        {poll, Ms} -> Ms;
                        _ -> maps:get(retry_max_ms, D#d.opts, 30000)
                    end,
            {keep_state, D1, [{{timeout, {stream, N}}, Delay, again}]}
    end;
http_done({sse, N, _}, Result, joined, D) ->
    %% An SSE subscription answered without streaming: an HTTP error, or gone.
    http_done({stream, N}, Result, joined, D);
http_done(_Purpose, _Result, _State, D) ->
    {keep_state, D}.

stream_message(timeout) -> <<"the Thing did not answer within request_timeout">>;
stream_message(too_large) -> <<"the Thing's answer is over max_body">>;
stream_message({status, S, _}) -> <<"the Thing answered HTTP ", (integer_to_binary(S))/binary>>.

open_stream(N, #d{opts = Opts, streams = Streams} = D) ->
    #{form := Form, mode := Mode} = maps:get(N, Streams),
    Http = #{method => maps:get(method, Form), url => maps:get(href, Form),
             headers => wot_avatar_route:headers(Form, maps:get(thing_credentials, Opts, #{})),
             content_type => maps:get(content_type, Form), body => none},
    case Mode of
        mqtt -> D;
        {poll, _} -> issue(Http, timeout(Opts), [], {stream, N}, D);
        longpoll -> issue(Http, maps:get(longpoll_ms, Opts, 60000), [], {stream, N}, D);
        sse -> issue(Http, infinity, [{stream, self}], {sse, N, <<>>}, D)
    end.

%% A reading of stream N: to every component bound to it (a polled one
%% only when it changed); kept for the partners that bind later.
push(N, Body, #d{streams = Streams, bound = Bound, entity = E} = D) ->
    #{type := Type, mode := Mode} = Stream = maps:get(N, Streams),
    #{component := C} = D#d.routes,
    {Params, Signals} = wot_avatar_route:reading(Stream, Body, wot_avatar_route:receivers(E, C, Type, Bound),
                                                 ctx(D)),
    case {Mode, maps:find(N, D#d.last)} of
        {{poll, _}, {ok, Params}} -> D;
        _ -> send(Signals, D#d{last = (D#d.last)#{N => Params}})
    end.

%% The components the streams' readings go to.
partners(#d{routes = undefined}) ->
    [];
partners(#d{routes = #{component := C}, entity = E, bound = Bound, streams = Streams}) ->
    lists:usort(lists:append([wot_avatar_route:receivers(E, C, T, Bound) || #{type := T} <- maps:values(Streams)])).

%% A new Binding report: new partners of a stream get its last reading.
rebound(Bound, #d{routes = #{component := C}, entity = E, bound = Old, streams = Streams} = D) ->
    Signals = [#{context => Ctx, sender => C, receiver => R,
                 body => #{category => <<"SENSOR">>, type => T, parameters => Ps}}
               || {N, #{type := T, context := Ctx}} <- lists:sort(maps:to_list(Streams)),
                  Ps <- [maps:get(N, D#d.last, [])], Ps =/= [],
                  R <- wot_avatar_route:receivers(E, C, T, Bound) -- wot_avatar_route:receivers(E, C, T, Old)],
    send(Signals, D#d{bound = Bound});
rebound(Bound, D) ->
    D#d{bound = Bound}.

send(Signals, #d{bridge = undefined} = D) ->
    _ = Signals,
    D;
send(Signals, #d{bridge = C} = D) ->
    _ = [agent_bridge_client:send(C, S) || S <- Signals],
    D.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

ctx(#d{routes = #{component := C}, opts = Opts}) ->
    maps:merge(maps:with([room], Opts), #{component => C}).

stream_type(N, #d{streams = S}) ->
    maps:get(type, maps:get(N, S)).

timeout(Opts) -> maps:get(request_timeout, Opts, 4000).

max_body(Opts) -> maps:get(max_body, Opts, 65536).

problem(Report, #d{problems = Ps, entity = E} = D) ->
    R = Report#{time => os:system_time(millisecond)},
    ?LOG_WARNING(R#{entity => E}),
    D#d{problems = lists:sublist([R | Ps], ?MAX_PROBLEMS)}.

text(B) when is_binary(B) -> B;
text(T) -> iolist_to_binary(io_lib:format("~0tp", [T])).
