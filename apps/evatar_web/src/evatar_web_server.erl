%% @doc Internal. Starts the HTTP server: OTP inets httpd, stand-alone
%% (linked to evatar_web_sup, not an inets service), with one module,
%% evatar_web_router, which answers every request. httpd's own limits are
%% set here (docs/api.md, "Limits").
-module(evatar_web_server).

-include_lib("kernel/include/logger.hrl").

-export([start_link/0, info/0, url/2, format_listening/1]).

%% @doc Starts httpd with the application environment's options, checked
%% first (evatar_web:check_opts/1) so a mistake says which key.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    Opts = maps:from_list([{K, V} || {K, V} <- application:get_all_env(evatar_web),
                                     K =/= included_applications]),
    case evatar_web:check_opts(Opts) of
        ok ->
            case evatar_web_auth:setup(Opts) of
                ok -> start_httpd(Opts);
                {error, _} = Error -> Error
            end;
        {error, {Key, Why}} ->
            {error, {bad_http_option, Key, Why}}
    end.

start_httpd(#{ip := Ip, port := Port} = Opts) ->
    Priv = code:priv_dir(evatar_web),
    MaxBody = maps:get(max_body, Opts),
    Config = [{port, Port},
              {bind_address, Ip},
              {ipfamily, case tuple_size(Ip) of 4 -> inet; 8 -> inet6 end},
              %% Not {socket_type, {ip_comm, [{nodelay, true}]}}: OTP 25's
              %% httpd cannot listen on a fixed port with it (function_clause
              %% in http_transport:listen/4; only port 0 worked). The router
              %% sets nodelay on each accepted socket instead.
              {server_name, "evatar"},
              {server_root, Priv},
              {document_root, filename:join(Priv, "www")},
              {modules, [evatar_web_router]},
              %% A declared length over max_body gets the router's JSON 413.
              {customize, evatar_web_limit},
              {max_clients, maps:get(max_clients, Opts)},
              {max_body_size, MaxBody},
              {max_content_length, MaxBody},
              {max_header_size, 16384},
              {max_uri_size, 4096},
              {keep_alive_timeout, 30},
              {max_keep_alive_request, 1000},
              {log_format, compact}],
    case inets:start(httpd, Config, stand_alone) of
        {ok, Pid} ->
            %% The instance's id carries the port bound (port 0 picks one).
            [Bound] = [P || {{httpd_instance_sup, _, P, _}, _, _, _} <- supervisor:which_children(Pid)],
            persistent_term:put(?MODULE, #{ip => Ip, port => Bound, max_body => MaxBody}),
            %% A report for log tools, and a line for a person (the port
            %% picked when configured with port 0).
            ?LOG_NOTICE(#{what => http_listening, ip => inet:ntoa(Ip), port => Bound,
                          url => url(Ip, Bound), operator_token => evatar_web_auth:configured()},
                        #{report_cb => fun ?MODULE:format_listening/1}),
            {ok, Pid};
        {error, Why} ->
            ?LOG_ERROR(#{what => http_listen_failed, ip => inet:ntoa(Ip), port => Port,
                         reason => Why}),
            {error, {http_listen_failed, Ip, Port, Why}}
    end.

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

%% @doc The listener's address, bound port and body limit; `undefined'
%% when the server has not started.
-spec info() -> #{ip := inet:ip_address(), port := inet:port_number(),
                  max_body := pos_integer()} | undefined.
info() ->
    case whereis(evatar_web_sup) =/= undefined andalso
        lists:keymember(evatar_web_server, 1, supervisor:which_children(evatar_web_sup)) of
        true -> persistent_term:get(?MODULE, undefined);
        false -> undefined
    end.
