%% Test helpers of evatar_web's suites: start the application on a free
%% port with given options, and make HTTP requests to it over real TCP
%% (httpc), decoding JSON answers.
-module(evatar_web_test).

-export([start/1, stop/0, restart/1, get/1, get/2, request/4, raw/4, raw_tcp/1, url/1]).

-define(PROFILE, evatar_web_test).

%% Starts evatar (and what it needs) and evatar_web with `Env' over the
%% test defaults (port 0).
start(Env) ->
    {ok, _} = application:ensure_all_started(inets),
    _ = inets:start(httpc, [{profile, ?PROFILE}]),
    restart(Env).

restart(Env) ->
    _ = application:stop(evatar_web),
    _ = application:load(evatar_web),
    Defaults = #{enabled => true, ip => {127, 0, 0, 1}, port => 0, operator_token_hash => undefined,
                 token_file => "", max_body => 1048576, max_clients => 64,
                 header_timeout => 10000},
    [ok = application:set_env(evatar_web, K, V) || {K, V} <- maps:to_list(maps:merge(Defaults, Env))],
    {ok, _} = application:ensure_all_started(evatar_web),
    ok.

stop() ->
    _ = application:stop(evatar_web),
    ok.

url(Path) ->
    "http://127.0.0.1:" ++ integer_to_list(evatar_web:port()) ++ Path.

get(Path) -> request(get, Path, [], none).
get(Path, Headers) -> request(get, Path, Headers, none).

%% A request whose answer is JSON: {Status, DecodedBody}.
request(Method, Path, Headers, Body) ->
    {Status, RespHeaders, RespBody} = raw(Method, Path, Headers, Body),
    "application/json" = proplists:get_value("content-type", RespHeaders),
    {ok, Json} = evatar_json:decode(list_to_binary(RespBody)),
    {Status, Json}.

%% Any request: {Status, Headers, Body (a string)}.
raw(Method, Path, Headers, Body) ->
    Req = case Body of
              none -> {url(Path), Headers};
              _ -> {url(Path), Headers, "application/json", Body}
          end,
    {ok, {{_, Status, _}, RespHeaders, RespBody}} =
        httpc:request(Method, Req, [{timeout, 30000}], [], ?PROFILE),
    {Status, RespHeaders, RespBody}.

%% Sends `Data' as it is on a new connection and returns all it gets back
%% until the server closes it or is quiet for 5 s: for requests a client
%% library would not send.
raw_tcp(Data) ->
    {ok, S} = gen_tcp:connect({127, 0, 0, 1}, evatar_web:port(), [binary, {active, false}]),
    _ = gen_tcp:send(S, Data),
    Reply = recv_all(S, []),
    _ = gen_tcp:close(S),
    Reply.

recv_all(S, Acc) ->
    case gen_tcp:recv(S, 0, 5000) of
        {ok, B} -> recv_all(S, [Acc, B]);
        {error, _} -> iolist_to_binary(Acc)
    end.
