%% @doc Internal. `GET /api/events?pairing=ID&kind=K1,K2&entity=E': a
%% pairing's live signal tail (evatar_tap) as server-sent events
%% (text/event-stream, docs/dashboard.md). The httpd request process runs
%% the stream itself: it writes the response head and each item on the
%% socket (httpd_socket:deliver/3) and loops until the client goes (the
%% socket is put in active-once mode, so a close is seen at once), a write
%% fails, or the server stops. A comment line every 15 s keeps proxies and
%% the browser's EventSource from timing out; httpd's own keep-alive
%% timeout does not run while a module is answering. Streams are admitted
%% by evatar_web_streams (at most half of `max_clients').
-module(evatar_web_events).

-include_lib("inets/include/httpd.hrl").

-export([stream/1]).

-define(KEEPALIVE_MS, 15000).
-define(MAX_PAIRING, 1024).

%% @doc The route's handler (evatar_web_router).
-spec stream(evatar_web_router:request()) -> evatar_web_router:reply().
stream(#{query := Query, mod := Mod}) ->
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
            admitted(Pairing, Filter, Mod)
    end.

param(Name, Query) ->
    case lists:keyfind(Name, 1, Query) of
        {_, V} when is_binary(V) -> V;
        _ -> <<>>
    end.

admitted(Pairing, Filter, Mod) ->
    case evatar_web_streams:admit() of
        ok ->
            case evatar_tap:watch(Pairing, Filter) of
                {ok, Sub} ->
                    run(Pairing, Filter, Sub, Mod);
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

run(Pairing, Filter, Sub, #mod{socket_type = Type, socket = Socket}) ->
    Head = ["HTTP/1.1 200 OK\r\n",
            "Content-Type: text/event-stream; charset=utf-8\r\n",
            "Cache-Control: no-store\r\n",
            "X-Content-Type-Options: nosniff\r\n",
            "Connection: close\r\n\r\n",
            event(#{kind => <<"hello">>, pairing => Pairing, node => atom_to_binary(node()),
                    filter => Filter, window => evatar_tap:window(),
                    at => erlang:system_time(millisecond)})],
    case httpd_socket:deliver(Type, Socket, Head) of
        ok ->
            ok = active_once(Type, Socket),
            Timer = erlang:send_after(?KEEPALIVE_MS, self(), {?MODULE, keepalive}),
            loop(Type, Socket, Sub, Timer);
        _ ->
            ok = evatar_tap:unwatch(Sub)
    end,
    %% The stream is over: the connection too (the close message, already
    %% taken here, would not reach httpd, which would wait for a next
    %% request until its keep-alive timeout).
    _ = http_transport:close(Type, Socket),
    ok = evatar_web_streams:release(),
    {proceed, [{response, {already_sent, 200, 0}}]}.

loop(Type, Socket, Sub, Timer) ->
    receive
        {Closed, Socket} when Closed =:= tcp_closed; Closed =:= ssl_closed ->
            stop(Sub, Timer);
        {Error, Socket, _} when Error =:= tcp_error; Error =:= ssl_error ->
            stop(Sub, Timer);
        {Data, Socket, _} when Data =:= tcp; Data =:= ssl ->
            %% Nothing is expected from an event stream's client.
            ok = active_once(Type, Socket),
            loop(Type, Socket, Sub, Timer);
        {'EXIT', _, Reason} ->
            %% httpd shutting the connection down (the handler traps exits).
            stop(Sub, Timer),
            exit(Reason);
        {?MODULE, keepalive} ->
            case httpd_socket:deliver(Type, Socket, <<": keepalive\n\n">>) of
                ok ->
                    loop(Type, Socket, Sub,
                         erlang:send_after(?KEEPALIVE_MS, self(), {?MODULE, keepalive}));
                _ ->
                    stop(Sub, Timer)
            end;
        Msg ->
            case evatar_tap:handle(Msg, Sub) of
                {items, [], Sub1} ->
                    loop(Type, Socket, Sub1, Timer);
                {items, Items, Sub1} ->
                    case httpd_socket:deliver(Type, Socket, [event(I) || I <- Items]) of
                        ok -> loop(Type, Socket, Sub1, Timer);
                        _ -> stop(Sub1, Timer)
                    end;
                ignore ->
                    loop(Type, Socket, Sub, Timer)
            end
    end.

stop(Sub, Timer) ->
    _ = erlang:cancel_timer(Timer),
    evatar_tap:unwatch(Sub).

event(Item) ->
    ["data: ", evatar_web_json:encode(Item), "\n\n"].

active_once(Type, Socket) when Type =:= ip_comm; element(1, Type) =:= ip_comm ->
    %% `{ip_comm, Options}' when the listener sets socket options (nodelay).
    case inet:setopts(Socket, [{active, once}]) of
        ok -> ok;
        %% Closed already: the loop's next write fails and ends it.
        {error, _} -> self() ! {tcp_closed, Socket}, ok
    end;
active_once(_Ssl, Socket) ->
    case ssl:setopts(Socket, [{active, once}]) of
        ok -> ok;
        {error, _} -> self() ! {ssl_closed, Socket}, ok
    end.
