%% @doc Internal. `GET /api/events?pairing=ID&kind=K1,K2&entity=E': a
%% pairing's live signal tail (evatar_tap) as server-sent events
%% (text/event-stream, docs/dashboard.md). cowboy's request process runs
%% the stream itself: it sends the response head (cowboy_req:stream_reply/3,
%% not chunked, `connection: close') and each item (stream_body/3) and
%% loops until the client goes: the connection process sees the close and
%% ends this process, whose monitors (evatar_tap's, evatar_web_streams')
%% then free its watch and its slot. The connection's idle timeout is off
%% for the stream (the client sends nothing); a comment line every 15 s
%% keeps proxies and the browser's EventSource from timing out. Streams are
%% admitted by evatar_web_streams (at most half of `max_clients'). HEAD
%% answers the head alone.
-module(evatar_web_events).

-export([stream/1]).

-define(KEEPALIVE_MS, 15000).
-define(MAX_PAIRING, 1024).

%% @doc The route's handler (evatar_web_router).
-spec stream(evatar_web_router:request()) -> evatar_web_router:reply().
stream(#{req := Req} = Request) ->
    case cowboy_req:method(Req) of
        <<"HEAD">> -> {raw, 200, headers(), <<>>};
        _ -> watch(Request)
    end.

watch(#{query := Query, req := Req}) ->
    Pairing = param(<<"pairing">>, Query),
    case {Pairing, evatar_tap:filter(param(<<"kind">>, Query), param(<<"entity">>, Query))} of
        {<<>>, _} ->
            {error, 400, <<"missing_field">>, <<"pairing">>,
             <<"name the pairing to watch: /api/events?pairing=ID">>};
        {_, _} when byte_size(Pairing) > ?MAX_PAIRING ->
            {error, 400, <<"bad_value">>, <<"pairing">>, <<"a pairing id is at most 1024 bytes">>};
        {_, {error, {bad_kind, Kind}}} ->
            {error, 400, <<"bad_value">>, <<"kind">>,
             iolist_to_binary(["unknown kind '", evatar_log:id(Kind), "'; the kinds: ",
                               lists:join(", ", evatar_tap:kinds())])};
        {_, {ok, Filter}} ->
            admitted(Pairing, Filter, Req)
    end.

param(Name, Query) ->
    case lists:keyfind(Name, 1, Query) of
        {_, V} when is_binary(V) -> V;
        _ -> <<>>
    end.

admitted(Pairing, Filter, Req) ->
    case evatar_web_streams:admit() of
        ok ->
            case evatar_tap:watch(Pairing, Filter) of
                {ok, Sub} ->
                    run(Pairing, Filter, Sub, Req);
                Error ->
                    ok = evatar_web_streams:release(),
                    refused(Pairing, Error)
            end;
        {error, too_many_streams} ->
            {error, 503, <<"too_many_streams">>, null,
             iolist_to_binary(io_lib:format("~b event streams are open on this node, its limit"
                                            " (half of max_clients)", [evatar_web_streams:max()]))}
    end.

refused(Pairing, {error, not_found}) ->
    {error, 404, <<"not_found">>, <<"pairing">>,
     <<"no pairing '", (evatar_log:id(Pairing))/binary, "' on this cluster">>};
refused(_Pairing, {error, too_many_watchers}) ->
    {error, 503, <<"too_many_watchers">>, <<"pairing">>,
     <<"this pairing has 16 watchers already; close one">>};
refused(_Pairing, {error, busy}) ->
    {error, 503, <<"busy">>, <<"pairing">>,
     <<"the pairing did not answer in time (or has no active now); try again">>}.

headers() ->
    [{"content-type", "text/event-stream; charset=utf-8"},
     {"cache-control", "no-store"},
     {"x-content-type-options", "nosniff"},
     {"connection", "close"}].

run(Pairing, Filter, Sub, Req0) ->
    %% Items as they come, not in chunks; no idle timeout (docs above).
    ok = cowboy_req:cast({set_options, #{idle_timeout => infinity, chunked => false}}, Req0),
    Req = cowboy_req:stream_reply(200, maps:from_list([{list_to_binary(K), list_to_binary(V)}
                                                       || {K, V} <- headers()]), Req0),
    ok = cowboy_req:stream_body(event(#{kind => <<"hello">>, pairing => Pairing,
                                        node => atom_to_binary(node()), filter => Filter,
                                        window => evatar_tap:window(),
                                        at => erlang:system_time(millisecond)}),
                                nofin, Req),
    Timer = erlang:send_after(?KEEPALIVE_MS, self(), {?MODULE, keepalive}),
    loop(Req, Sub, Timer).

%% Runs until the process is ended with the connection.
loop(Req, Sub, Timer) ->
    receive
        {?MODULE, keepalive} ->
            ok = cowboy_req:stream_body(<<": keepalive\n\n">>, nofin, Req),
            loop(Req, Sub, erlang:send_after(?KEEPALIVE_MS, self(), {?MODULE, keepalive}));
        Msg ->
            case evatar_tap:handle(Msg, Sub) of
                {items, [], Sub1} ->
                    loop(Req, Sub1, Timer);
                {items, Items, Sub1} ->
                    ok = cowboy_req:stream_body([event(I) || I <- Items], nofin, Req),
                    loop(Req, Sub1, Timer);
                ignore ->
                    loop(Req, Sub, Timer)
            end
    end.

event(Item) ->
    ["data: ", evatar_json:encode(Item), "\n\n"].
