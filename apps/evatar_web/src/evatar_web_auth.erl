%% @doc Internal. The operator credential of the HTTP API (docs/api.md,
%% "Authentication"): one token, kept only as its PBKDF2 hash (the
%% credentials' scheme, evatar:hash_credential/1). Changes always need it
%% (`Authorization: Bearer TOKEN'); reads need it too unless the listener
%% is on a loopback address, and there only with a loopback `Host' header
%% (against DNS rebinding). With no token configured every change is
%% refused: there is no default secret.
-module(evatar_web_auth).

-export([setup/1, check/3, configured/0]).

-export_type([verdict/0]).

-type verdict() :: ok | {error, 401 | 403, binary(), binary()}.

-define(KEY, {?MODULE, config}).

%% @doc Reads the configured token (`operator_token_hash', or the first
%% line of `token_file', hashed at once) and keeps it for check/3.
-spec setup(#{atom() => term()}) -> ok | {error, {atom(), binary()}}.
setup(Opts) ->
    Ip = maps:get(ip, Opts),
    case token(maps:get(operator_token_hash, Opts, undefined), maps:get(token_file, Opts, "")) of
        {ok, Hash} ->
            persistent_term:put(?KEY, #{hash => Hash, loopback => loopback(Ip)});
        {error, _} = Error ->
            Error
    end.

token(undefined, File) when File =:= ""; File =:= <<>>; File =:= undefined ->
    {ok, none};
token(undefined, File) ->
    case file:read_file(File) of
        {ok, Bin} ->
            case string:trim(hd(binary:split(Bin, <<"\n">>)), trailing, "\r") of
                <<>> -> {error, {token_file, <<"the token file's first line is empty">>}};
                Token -> {ok, evatar:hash_credential(Token)}
            end;
        {error, Why} ->
            {error, {token_file, iolist_to_binary(["cannot read ", File, ": ",
                                                    file:format_error(Why)])}}
    end;
token(Hash, File) when File =:= ""; File =:= <<>>; File =:= undefined ->
    {ok, Hash};
token(_Hash, _File) ->
    {error, {token_file, <<"give operator_token_hash or a token file, not both">>}}.

%% @doc Whether an operator token is configured.
-spec configured() -> boolean().
configured() ->
    maps:get(hash, config()) =/= none.

config() ->
    persistent_term:get(?KEY, #{hash => none, loopback => true}).

%% @doc The verdict on a request: its kind (`read' or `change'), its
%% `authorization' and `host' headers (as strings; `undefined' when absent).
-spec check(read | change, string() | undefined, string() | undefined) -> verdict().
check(Kind, Authorization, Host) ->
    #{hash := Hash, loopback := Loopback} = config(),
    case {Kind, Hash, bearer(Authorization)} of
        {read, _, none} when Loopback ->
            loopback_host(Host);
        {change, none, _} ->
            {error, 403, <<"no_operator_token">>,
             <<"changes are refused until an operator token is configured: put its hash "
               "(bin/evatar hash_credential) in the node configuration file's http section as "
               "operator_token_hash, or name a file holding it in EVATAR_HTTP_TOKEN_FILE">>};
        {read, none, _} ->
            {error, 403, <<"no_operator_token">>,
             <<"this listener is not on a loopback address, so reads need the operator token, "
               "and none is configured (docs/api.md, Authentication)">>};
        {_, _, none} ->
            {error, 401, <<"unauthorized">>,
             <<"this needs the operator token: Authorization: Bearer TOKEN">>};
        {_, _, bad} ->
            {error, 401, <<"unauthorized">>,
             <<"the Authorization header must be: Bearer TOKEN">>};
        {_, _, {ok, Token}} ->
            case evatar:verify_credential(Hash, Token) of
                true -> ok;
                false -> {error, 401, <<"bad_token">>, <<"the operator token is wrong">>}
            end
    end.

bearer(undefined) ->
    none;
bearer(Header) ->
    case string:split(string:trim(Header), " ") of
        [Scheme, Token] ->
            case {string:lowercase(Scheme), string:trim(Token)} of
                {"bearer", [_ | _] = T} -> {ok, unicode:characters_to_binary(T, latin1)};
                _ -> bad
            end;
        _ ->
            bad
    end.

%% Open reads on a loopback listener still check the Host header, so that a
%% web page elsewhere cannot read the API through DNS rebinding (a name of
%% its own resolving to 127.0.0.1).
loopback_host(Host) ->
    Name = case Host of
               undefined -> "";
               "[" ++ Rest -> hd(string:split(Rest, "]"));
               _ -> hd(string:split(Host, ":"))
           end,
    case string:lowercase(Name) of
        N when N =:= "localhost"; N =:= "::1" -> ok;
        N ->
            case inet:parse_ipv4strict_address(N) of
                {ok, {127, _, _, _}} -> ok;
                _ -> {error, 403, <<"bad_host">>,
                      <<"reads without the operator token are answered only to a loopback "
                        "Host (localhost, 127.0.0.1, [::1])">>}
            end
    end.

loopback({127, _, _, _}) -> true;
loopback({0, 0, 0, 0, 0, 0, 0, 1}) -> true;
loopback(_) -> false.
