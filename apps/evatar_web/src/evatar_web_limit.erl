%% @doc Internal. httpd's `customize' callback (httpd_custom): a request
%% whose declared Content-Length is over `max_body' has that header
%% renamed to `x-evatar-body-too-large' before httpd acts on it, so httpd
%% reads no body and calls evatar_web_router, which answers the JSON
%% 413 `body_too_large' and closes the connection (docs/api.md, "Limits").
%% httpd's own check would answer an HTML page instead.
-module(evatar_web_limit).

-export([request_header/1, response_header/1, response_default_headers/0, too_large_header/0]).

%% @doc The renamed header: present in a request only when its declared
%% length is over the limit.
-spec too_large_header() -> string().
too_large_header() -> "x-evatar-body-too-large".

%% @doc Renames a Content-Length over the limit; every other header is
%% kept as it is. A client cannot set the renamed header itself to a
%% small value to pass: the router re-checks the value against the limit.
-spec request_header({string(), string()}) -> {true, {string(), string()}}.
request_header({"content-length", Value} = Header) ->
    case over_limit(Value) of
        true -> {true, {too_large_header(), Value}};
        false -> {true, Header}
    end;
request_header(Header) ->
    {true, Header}.

%% @doc Keeps every response header.
-spec response_header({string(), string()}) -> {true, {string(), string()}}.
response_header(Header) ->
    {true, Header}.

%% @doc No extra response headers.
-spec response_default_headers() -> [].
response_default_headers() ->
    [].

over_limit(Value) ->
    case string:to_integer(string:trim(Value)) of
        {N, []} when is_integer(N) -> N > evatar_web_router:max_body();
        _ -> false
    end.
