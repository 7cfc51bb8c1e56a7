%% @doc Public API of evatar_web, EVATAR's HTTP side: the operator's JSON
%% API (docs/api.md) and the dashboard's files, served by cowboy (ranch's
%% listener, evatar_web_server) with one handler of ours, evatar_web_router.
%% The operations themselves
%% are evatar_ops's, shared with the release's commands. Every other
%% evatar_web_* module is internal.
-module(evatar_web).

-export([port/0, url/0, check_opts/1, default/1]).

-export_type([opts/0]).

%% The application environment (docs/api.md, "Configuration"): `enabled'
%% (true), `ip' (127.0.0.1), `port' (7480; 0 picks a free one),
%% `operator_token_hash' (none), `token_file' (none), `max_body' (1 MiB),
%% `max_clients' (64), `header_timeout' (10000 ms: the request line and
%% headers must have arrived this long after the connection opened or the
%% last answer), `things' (none: the WoT consumers, docs/wot.md).
-type opts() :: #{enabled => boolean(),
                  ip => inet:ip_address(),
                  port => inet:port_number(),
                  operator_token_hash => undefined | evatar_auth:hashed(),
                  token_file => string() | binary(),
                  max_body => pos_integer(),
                  max_clients => pos_integer(),
                  header_timeout => pos_integer(),
                  things => [#{pairing := binary() | string(),
                               credential := binary() | string(),
                               entity_id => binary() | string()}]}.

-define(KEYS, [enabled, ip, port, operator_token_hash, token_file, max_body, max_clients,
               header_timeout, things]).

%% @doc The port the HTTP server listens on (the one it picked when
%% configured with port 0); `undefined' when it does not run.
-spec port() -> inet:port_number() | undefined.
port() ->
    case evatar_web_server:info() of
        #{port := Port} -> Port;
        undefined -> undefined
    end.

%% @doc The page's address, "http://IP:PORT/" as a string (the shell
%% prints it as it is); `undefined' when the server does not run.
-spec url() -> string() | undefined.
url() ->
    case evatar_web_server:info() of
        #{ip := Ip, port := Port} -> evatar_web_server:url(Ip, Port);
        undefined ->
            undefined
    end.

%% @doc The default of an option that may be left out of the environment.
-spec default(header_timeout) -> pos_integer().
default(header_timeout) -> 10000.

%% @doc Pure: checks the options (the environment's, or the node
%% configuration file's `http' section); the error names the key.
-spec check_opts(term()) -> ok | {error, {atom() | term(), binary()}}.
check_opts(Opts) when is_map(Opts) ->
    case [K || K <- maps:keys(Opts), not lists:member(K, ?KEYS)] of
        [] -> check(lists:sort(maps:to_list(Opts)));
        [K | _] -> {error, {K, iolist_to_binary(io_lib:format("unknown key (known: ~ts)",
                                                              [lists:join(", ", [atom_to_list(A) || A <- ?KEYS])]))}}
    end;
check_opts(_) ->
    {error, {http, <<"must be a map">>}}.

thing(#{pairing := P, credential := C} = T) ->
    lists:all(fun text/1, [P, C | [E || #{entity_id := E} <- [T]]])
        andalso maps:size(maps:without([pairing, credential, entity_id], T)) =:= 0;
thing(_) ->
    false.

text(B) when is_binary(B), B =/= <<>> -> true;
text([_ | _] = L) -> io_lib:printable_unicode_list(L);
text(_) -> false.

check([]) -> ok;
check([{K, V} | Rest]) ->
    case valid(K, V) of
        true -> check(Rest);
        Why -> {error, {K, Why}}
    end.

valid(enabled, V) when is_boolean(V) -> true;
valid(enabled, _) -> <<"must be true or false">>;
valid(ip, V) ->
    case inet:is_ip_address(V) of
        true -> true;
        false -> <<"must be an IP address">>
    end;
valid(port, V) when is_integer(V), V >= 0, V < 65536 -> true;
valid(port, _) -> <<"must be a port number, 0 to 65535 (0: one picked at start)">>;
valid(operator_token_hash, undefined) -> true;
valid(operator_token_hash, V) ->
    %% evatar's own check of a hashed credential.
    case evatar:check_pairing_opts(#{agent_credential => V, avatar_credential => V}) of
        ok when is_tuple(V) -> true;
        _ -> <<"must be a hashed credential as bin/evatar hash_credential prints it">>
    end;
valid(token_file, V) when is_list(V) ->
    case io_lib:printable_unicode_list(V) of
        true -> true;
        false -> <<"must be a file name">>
    end;
valid(token_file, V) when is_binary(V) -> true;
valid(token_file, _) -> <<"must be a file name">>;
valid(things, V) when is_list(V) ->
    Pairings = [P || #{pairing := P} <- V],
    Unique = length(lists:usort(Pairings)) =:= length(Pairings),
    case lists:all(fun thing/1, V) of
        false -> <<"must be a list of #{pairing => Id, credential => Secret, entity_id => Id} "
                   "(texts; entity_id optional, default wot)">>;
        true when not Unique ->
            <<"names a pairing more than once (one WoT consumer per pairing)">>;
        true -> true
    end;
valid(things, _) -> <<"must be a list">>;
valid(header_timeout, V) when is_integer(V), V > 0, V =< 3600000 -> true;
valid(header_timeout, _) -> <<"must be a time in milliseconds, 1 to 3600000">>;
valid(K, V) when K =:= max_body; K =:= max_clients ->
    case is_integer(V) andalso V > 0 of
        true -> true;
        false -> <<"must be a positive integer">>
    end.
