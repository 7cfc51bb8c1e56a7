%% @doc Internal. What the HTTP server does around cowboy, per connection:
%% the ranch protocol of the listener (start_link/3), which answers a
%% connection past `max_clients' with the JSON 503 `too_many_clients' and
%% closes it, and hands every other one to cowboy (cowboy_clear); and the
%% first cowboy stream handler (init/3 ... early_error/5), which gives the
%% API's JSON error body (docs/api.md, "Errors") to the answers cowboy
%% makes itself: before any handler runs (400 bad request line or header,
%% 408 headers too slow, 414 URI too long, 431 headers too large, 501
%% TRACE and CONNECT, 505) and when a request process ends without one.
-module(evatar_web_conn).
-behaviour(ranch_protocol).
-behaviour(cowboy_stream).

-export([start_link/3, over_limit/4]).
-export([init/3, data/4, info/3, terminate/3, early_error/5]).

%% @doc ranch's callback: a connection process.
-spec start_link(ranch:ref(), module(), cowboy:opts()) -> {ok, pid()}.
start_link(Ref, Transport, Opts) ->
    {ok, proc_lib:spawn_link(?MODULE, over_limit, [self(), Ref, Transport, Opts])}.

%% @private The connection process: counted among the listener's open
%% connections (itself included) before cowboy takes it over.
-spec over_limit(pid(), ranch:ref(), module(), cowboy:opts()) -> ok.
over_limit(Parent, Ref, Transport, #{env := #{max_clients := Max}} = Opts) ->
    case length(ranch:procs(Ref, connections)) > Max of
        false ->
            cowboy_clear:connection_process(Parent, Ref, Transport, Opts);
        true ->
            {ok, Socket} = ranch:handshake(Ref),
            Body = evatar_json:encode(
                     #{error => <<"too_many_clients">>, field => null,
                       message => iolist_to_binary(
                                    io_lib:format("~b connections are open, this node's limit "
                                                  "(http.max_clients, docs/api.md); try again",
                                                  [Max]))}),
            _ = Transport:send(Socket, [cow_http:response(503, 'HTTP/1.1', headers(Body)), Body]),
            %% The request is not read: close our side, then let the
            %% client's bytes drain a moment so the answer is not lost to
            %% a reset.
            _ = Transport:shutdown(Socket, write),
            drain(Transport, Socket, erlang:monotonic_time(millisecond) + 1000),
            _ = Transport:close(Socket),
            ok
    end.

drain(Transport, Socket, Until) ->
    Left = Until - erlang:monotonic_time(millisecond),
    case Left > 0 andalso Transport:recv(Socket, 0, Left) of
        {ok, _} -> drain(Transport, Socket, Until);
        _ -> ok
    end.

headers(Body) ->
    [{<<"content-type">>, <<"application/json">>},
     {<<"content-length">>, integer_to_binary(byte_size(Body))},
     {<<"cache-control">>, <<"no-store">>},
     {<<"x-content-type-options">>, <<"nosniff">>},
     {<<"connection">>, <<"close">>}].

%% ---------------------------------------------------------------------------
%% cowboy_stream: the next handler's commands, with a JSON body in each
%% error response cowboy makes itself (a request process that crashed or
%% that cowboy refused a read of: 400, 408, 413, 500).
%% ---------------------------------------------------------------------------

%% @private
-spec init(cowboy_stream:streamid(), cowboy_req:req(), cowboy:opts()) ->
          {cowboy_stream:commands(), term()}.
init(StreamID, Req, Opts) ->
    json_errors(cowboy_stream:init(StreamID, Req, Opts)).

%% @private
-spec data(cowboy_stream:streamid(), cowboy_stream:fin(), binary(), term()) ->
          {cowboy_stream:commands(), term()}.
data(StreamID, IsFin, Data, Next) ->
    json_errors(cowboy_stream:data(StreamID, IsFin, Data, Next)).

%% @private
-spec info(cowboy_stream:streamid(), any(), term()) -> {cowboy_stream:commands(), term()}.
info(StreamID, Info, Next) ->
    json_errors(cowboy_stream:info(StreamID, Info, Next)).

json_errors({Commands, Next}) ->
    {[case C of
          {error_response, Status, Headers, _} ->
              Body = evatar_json:encode(
                       #{error => code(Status), field => null,
                         message => case Status of
                                        500 -> <<"the request failed inside the node; its log has "
                                                 "the details">>;
                                        _ -> <<"the request could not be read">>
                                    end}),
              {error_response, Status, maps:merge(Headers, maps:from_list(headers(Body))), Body};
          _ ->
              C
      end || C <- Commands], Next}.

%% @private
-spec terminate(cowboy_stream:streamid(), cowboy_stream:reason(), term()) -> any().
terminate(StreamID, Reason, Next) ->
    cowboy_stream:terminate(StreamID, Reason, Next).

%% @private The response cowboy sends for a request it refused itself, with
%% the API's JSON body; its status and headers (connection: close) stay.
-spec early_error(cowboy_stream:streamid(), cowboy_stream:reason(), cowboy_stream:partial_req(),
                  Resp, cowboy:opts()) -> Resp
              when Resp :: cowboy_stream:resp_command().
early_error(StreamID, Reason, PartialReq, Resp0, Opts) ->
    {response, Status, Headers, _} =
        cowboy_stream:early_error(StreamID, Reason, PartialReq, Resp0, Opts),
    Body = evatar_json:encode(#{error => code(Status), field => null,
                                    message => message(Reason)}),
    {response, Status,
     maps:merge(Headers, maps:from_list(headers(Body))),
     Body}.

code(400) -> <<"bad_request">>;
code(408) -> <<"request_timeout">>;
code(413) -> <<"body_too_large">>;
code(500) -> <<"internal">>;
code(414) -> <<"uri_too_long">>;
code(431) -> <<"headers_too_large">>;
code(501) -> <<"not_implemented">>;
code(505) -> <<"http_version_not_supported">>;
code(_) -> <<"internal">>.

%% cowboy's reasons end with a sentence for a person.
message({_, _, Text}) when is_atom(Text) -> atom_to_binary(Text);
message(_) -> <<"the request was refused before it was read">>.
