%% @doc Public API of the node configuration file: one file of Erlang terms
%% (README.md, "Configuration"; the release ships a commented example as
%% etc/evatar.config) declaring the node's listeners, the pairings to
%% create when absent and the MQTT Avatars to keep running. The
%% `node_config' application reads it at boot, before evatar, agent_bridge
%% and mqtt_avatar start, and fills their environment; a file with mistakes
%% stops the start with every mistake named. Other node_config_* modules
%% are internal.
%%
%% Boot: the release lists node_config right after sasl. A file with
%% mistakes makes the start fail with `{bad_config, File, Problems}', each
%% problem naming the line, the section, the entry (number and id) and what
%% is wrong, printed on standard error and logged (`what =>
%% bad_node_config'); under the release's boot script the node then halts
%% with status 1 (no "Kernel pid terminated", no erl_crash.dump), before
%% any listener, pairing or Avatar started. The same check (check_file/0)
%% runs as `bin/evatar check_config' and as the start script's pre-start
%% hook, so `bin/evatar daemon' refuses on the terminal
%% (config/hooks/pre_start_config, config/extensions/check_config). A
%% pairing entry takes every option evatar:check_pairing_opts/1 accepts:
%% node_config_check turns the text into binaries, leaves the verdict to
%% evatar, words its `{bad_option, _}' with the entry's line, and asks again
%% without each refused key so that every refused key is named. A
%% credential may be written as its hash (`bin/evatar hash_credential',
%% hashed_credential/1).
%%
%% Why Erlang terms: OTP's own scanner and parser read them (what
%% file:consult/1 uses), so no Hex package and no parser of our own, and
%% the values map to the applications' options without a conversion layer;
%% YAML or TOML would need a Hex parser (none in Debian's erlang-*
%% packages), JSON has no comments and OTP 25 has no `json' module. Text is
%% written in double quotes and becomes a binary, never an atom, and
%% node_config_file refuses any atom the text spells that is neither a word
%% of the file nor an existing atom, so a misspelt key is an error that
%% names it and never a new atom.
-module(node_config).

-export([file/0, load/1, apply_env/1, format_error/1, check_file/0, hashed_credential/1,
         hash_credential_cli/0]).

-export_type([config/0]).

-type config() :: node_config_check:config().

%% @doc The file this node reads: `$EVATAR_CONFIG' when set, else the
%% application environment's `file', else etc/evatar.config in the release
%% (only if it exists); `none' when there is no file.
-spec file() -> {explicit | default, file:filename()} | none.
file() ->
    case os:getenv("EVATAR_CONFIG") of
        Path when is_list(Path), Path =/= "" ->
            {explicit, Path};
        _ ->
            case application:get_env(node_config, file) of
                {ok, Path} -> {explicit, Path};
                undefined ->
                    Default = filename:join([release_root(), "etc", "evatar.config"]),
                    case filelib:is_regular(Default) of
                        true -> {default, Default};
                        false -> none
                    end
            end
    end.

%% In a release, this application's directory is ROOT/lib/node_config-VSN.
release_root() ->
    filename:dirname(filename:dirname(code:lib_dir(node_config))).

%% @doc Reads and checks a configuration file. The agent_bridge
%% environment's listeners (loaded, not necessarily running) are the
%% default an MQTT or WoT Avatar joins when the file declares no listeners.
-spec load(file:filename()) -> {ok, config()} | {error, {bad_config, file:filename(), [binary()]}}.
load(File) ->
    Apps = [agent_bridge, evatar, mqtt_avatar, wot_avatar, mqtt_client, ssl, evatar_web],
    _ = [application:load(A) || A <- Apps],
    %% Their checks run before they start; the words their options use
    %% exist as atoms once their code is loaded (a listener limit, a TLS
    %% option such as verify_peer), as in a release, which loads every
    %% module at boot.
    _ = [code:ensure_loaded(M) || A <- Apps, {ok, Ms} <- [application:get_key(A, modules)], M <- Ms],
    case node_config_file:read(File, node_config_check:known_words()) of
        {ok, Sections, WordProblems} ->
            Defaults = #{listeners => application:get_env(agent_bridge, listeners, []),
                         dir => filename:dirname(filename:absname(File))},
            case node_config_check:check(Sections, Defaults, WordProblems) of
                {ok, Config} -> {ok, Config};
                {error, Problems} -> {error, {bad_config, File, Problems}}
            end;
        {error, Problem} ->
            {error, {bad_config, File, [Problem]}}
    end.

%% @doc Fills the environment of the applications that run what the file
%% declares: agent_bridge's `listeners' (when the file has a listeners
%% section: they replace the release's EVATAR_IP/EVATAR_PORT listener),
%% evatar's `pairings' (added to any already there; the file's win on the
%% same id), mqtt_avatar's and wot_avatar's `avatars', and evatar_web's options the http
%% section gives (they win over the EVATAR_HTTP* variables; an
%% operator_token_hash there replaces EVATAR_HTTP_TOKEN_FILE).
-spec apply_env(config()) -> ok.
apply_env(#{listeners := Listeners, pairings := Pairings, mqtt_avatars := Avatars,
            wot_avatars := Things} = Config) ->
    Http = maps:get(http, Config, #{}),
    Http1 = case Http of
                #{operator_token_hash := _} when not is_map_key(token_file, Http) ->
                    Http#{token_file => ""};
                _ ->
                    Http
            end,
    _ = [ok = application:set_env(evatar_web, K, V, [{persistent, true}])
         || {K, V} <- maps:to_list(Http1)],
    case Listeners of
        undefined -> ok;
        _ -> ok = application:set_env(agent_bridge, listeners, Listeners, [{persistent, true}])
    end,
    Ids = [Id || #{id := Id} <- Pairings],
    Kept = [P || P <- application:get_env(evatar, pairings, []),
                 not (is_map(P) andalso lists:member(maps:get(id, P, undefined), Ids))],
    ok = application:set_env(evatar, pairings, Kept ++ Pairings, [{persistent, true}]),
    ok = application:set_env(mqtt_avatar, avatars, Avatars, [{persistent, true}]),
    ok = application:set_env(wot_avatar, avatars, Things, [{persistent, true}]).

%% @doc For `bin/evatar check_config' and the start script's pre-start
%% hook: checks this node's file (file/0), prints the verdict, and returns
%% the exit status (0 good or no file, 1 mistakes).
-spec check_file() -> 0 | 1.
check_file() ->
    case file() of
        none ->
            io:format("no configuration file (EVATAR_CONFIG unset, no etc/evatar.config)~n"),
            0;
        {_, File} ->
            case load(File) of
                {ok, #{pairings := Ps, mqtt_avatars := As, wot_avatars := Ws} = Config} ->
                    %% The WoT count only when there are some: the line
                    %% stays what scripts read from earlier releases.
                    io:format("~ts: ok (~ts, ~b pairing(s), ~b MQTT Avatar(s)~ts)~n",
                              [File, case maps:get(listeners, Config) of
                                         undefined -> "the environment's listener";
                                         Ls -> io_lib:format("~b listener(s)", [length(Ls)])
                                     end, length(Ps), length(As),
                               case Ws of
                                   [] -> "";
                                   _ -> io_lib:format(", ~b WoT Avatar(s)", [length(Ws)])
                               end]),
                    0;
                {error, Reason} ->
                    io:put_chars(standard_error, ["EVATAR will not start: the configuration file has "
                                                  "mistakes\n", format_error(Reason)]),
                    1
            end
    end.

%% @doc A readable text of load/1's error: the file, then one line per
%% mistake.
-spec format_error({bad_config, file:filename(), [binary()]}) -> binary().
format_error({bad_config, File, Problems}) ->
    iolist_to_binary([io_lib:format("~ts: ~ts~n", [File, P]) || P <- Problems]).

%% @doc A credential's hashed form as the file takes it in place of the
%% plain text (`agent_credential', `avatar_credential', an identity's
%% `credential'): `{pbkdf2_sha256, Iterations, <<Salt>>, <<Hash>>}' of
%% evatar:hash_credential/1, one line. The file then holds no secret a
%% reader could use to join.
-spec hashed_credential(binary()) -> binary().
hashed_credential(Secret) when is_binary(Secret), Secret =/= <<>> ->
    {pbkdf2_sha256, I, Salt, Hash} = evatar:hash_credential(Secret),
    iolist_to_binary(io_lib:format("{pbkdf2_sha256, ~b, ~w, ~w}", [I, Salt, Hash])).

%% @doc For `bin/evatar hash_credential': reads a secret (one line) from
%% standard input and prints its hashed form (hashed_credential/1); returns
%% the exit status (1 for an empty secret).
-spec hash_credential_cli() -> 0 | 1.
hash_credential_cli() ->
    Secret = case io:get_line("") of
                 Line when is_list(Line); is_binary(Line) ->
                     unicode:characters_to_binary(string:trim(Line, trailing, "\r\n"));
                 _ ->
                     <<>>
             end,
    case Secret of
        <<_, _/binary>> ->
            io:format("~ts~n", [hashed_credential(Secret)]),
            0;
        _ ->
            io:put_chars(standard_error, "no secret given (an empty credential is refused)\n"),
            1
    end.
