%% @doc Internal. Starts the HTTP server: a ranch listener (embedded: its
%% supervisor is this child of evatar_web_sup) whose connections run
%% cowboy's HTTP/1.1 through evatar_web_conn, with one handler of ours,
%% evatar_web_router, for every request. The limits of docs/api.md
%% ("Limits") are set here as cowboy's and ranch's options.
%%
%% Why cowboy 2.8 (with ranch 2.1 and cowlib 2.9) rather than OTP's inets
%% httpd: httpd answered three things before any of our code ran, so they
%% could not be fixed: a chunked body over the limit was neither answered
%% nor closed, OPTIONS and unknown methods got its HTML 501, and a client
%% trickling its headers held its connection for ever. Hex cannot be
%% reached, so the three are Debian's beams, built for this OTP, taken from
%% its `rabbitmq-server' package (pinned, downloaded, never installed) by
%% scripts/ensure-deps.sh into _deps/; rebar.config.script puts them on the
%% code path and in ERL_LIBS for the nodes tests start, and the release
%% copies them into its lib/. The listener starts after
%% evatar_web:check_opts/1 (a mistake names the key); a port that cannot be
%% opened stops the application's start with `{http_listen_failed, Ip,
%% Port, Reason}'. cowboy's `request_timeout' is our `header_timeout'.
-module(evatar_web_server).

-include_lib("kernel/include/logger.hrl").

-export([start_link/0, info/0, url/2, format_listening/1]).

-define(REF, evatar_web_http).

%% @doc Starts the listener with the application environment's options,
%% checked first (evatar_web:check_opts/1) so a mistake says which key.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    Opts = maps:from_list([{K, V} || {K, V} <- application:get_all_env(evatar_web),
                                     K =/= included_applications]),
    case evatar_web:check_opts(Opts) of
        ok ->
            case evatar_web_auth:setup(Opts) of
                ok -> start_listener(Opts);
                {error, _} = Error -> Error
            end;
        {error, {Key, Why}} ->
            {error, {bad_http_option, Key, Why}}
    end.

start_listener(#{ip := Ip, port := Port} = Opts) ->
    MaxBody = maps:get(max_body, Opts),
    MaxClients = maps:get(max_clients, Opts),
    HeaderTimeout = maps:get(header_timeout, Opts, evatar_web:default(header_timeout)),
    Family = case tuple_size(Ip) of 4 -> inet; 8 -> inet6 end,
    TransOpts = #{socket_opts => [Family, {ip, Ip}, {port, Port},
                                  %% A response goes out in more than one send
                                  %% (head, body): Nagle would hold the second
                                  %% until the client's delayed ACK (about 40 ms
                                  %% a request on a kept-alive connection).
                                  {nodelay, true}],
                  %% Past max_clients a connection is still accepted, to be
                  %% answered 503 by evatar_web_conn; past twice that ranch
                  %% stops accepting and the kernel's backlog holds them.
                  max_connections => 2 * MaxClients,
                  num_acceptors => 4},
    ProtoOpts = #{env => #{max_clients => MaxClients},
                  middlewares => [evatar_web_router],
                  stream_handlers => [evatar_web_conn, cowboy_stream_h],
                  protocols => [http],
                  %% The request line and headers must have arrived this long
                  %% after the connection opened or the last answer went out
                  %% (so it is the idle keep-alive time too): a client that
                  %% trickles them gets a 408 and the connection closes.
                  request_timeout => HeaderTimeout,
                  %% No byte from the client this long while a request is
                  %% being read or answered (an event stream turns it off).
                  idle_timeout => 30000,
                  max_keepalive => 1000,
                  max_request_line_length => 4096,
                  max_header_value_length => 8192,
                  max_headers => 100,
                  max_skip_body_length => MaxBody},
    #{start := {M, F, A}} = ranch:child_spec(?REF, ranch_tcp, TransOpts, evatar_web_conn, ProtoOpts),
    case apply(M, F, A) of
        {ok, Pid} ->
            Bound = ranch:get_port(?REF),
            persistent_term:put(?MODULE, #{ip => Ip, port => Bound, max_body => MaxBody,
                                           max_clients => MaxClients}),
            %% A report for log tools, and a line for a person (the port
            %% picked when configured with port 0).
            ?LOG_NOTICE(#{what => http_listening, ip => inet:ntoa(Ip), port => Bound,
                          url => url(Ip, Bound), operator_token => evatar_web_auth:configured()},
                        #{report_cb => fun ?MODULE:format_listening/1}),
            {ok, Pid};
        {error, Error} ->
            Why = listen_error(Error),
            ?LOG_ERROR(#{what => http_listen_failed, ip => inet:ntoa(Ip), port => Port,
                         reason => Why}),
            {error, {http_listen_failed, Ip, Port, Why}}
    end.

%% ranch's acceptors exit with {listen_error, Ref, Reason}, nested in the
%% start errors of its supervisors.
listen_error({listen_error, ?REF, Why}) -> Why;
listen_error(T) when is_tuple(T) -> listen_error(tuple_to_list(T));
listen_error([H | Rest]) ->
    case listen_error(H) of
        undefined -> listen_error(Rest);
        Why -> Why
    end;
listen_error(_) -> undefined.

%% @doc Pure: "http://IP:PORT/" (an IPv6 address in brackets).
-spec url(inet:ip_address(), inet:port_number()) -> string().
url(Ip, Port) ->
    Host = case Ip of
               {_, _, _, _} -> inet:ntoa(Ip);
               _ -> "[" ++ inet:ntoa(Ip) ++ "]"
           end,
    lists:flatten(io_lib:format("http://~ts:~b/", [Host, Port])).

%% @doc The log line of the `http_listening' report.
-spec format_listening(#{url := string(), operator_token := boolean(), _ => _}) ->
          {io:format(), [term()]}.
format_listening(#{url := Url, operator_token := Token}) ->
    {"HTTP API and dashboard listening on ~ts (operator token ~ts)",
     [Url, case Token of true -> "configured"; false -> "not configured: changes refused" end]}.

%% @doc The listener's address, bound port and limits; `undefined' when
%% the server has not started.
-spec info() -> #{ip := inet:ip_address(), port := inet:port_number(),
                  max_body := pos_integer(), max_clients := pos_integer()} | undefined.
info() ->
    case whereis(evatar_web_sup) =/= undefined andalso
        lists:keymember(evatar_web_server, 1, supervisor:which_children(evatar_web_sup)) of
        true -> persistent_term:get(?MODULE, undefined);
        false -> undefined
    end.
