%% @doc Internal. Pure: checks the sections of a node configuration file
%% (node_config_file) and turns them into what the applications take:
%% agent_bridge listeners, evatar pairings, mqtt_avatar and wot_avatar
%% options. Every
%% problem names the section, the entry (its line, its number and its id)
%% and what is wrong; text written as "..." becomes a binary, never an atom.
%% An entry's independent mistakes are all reported, one line each (at
%% most ?MAX_MISTAKES an entry); a check that needs others to pass first
%% (an Avatar's pairing, its options as mqtt_avatar or wot_avatar takes
%% them) runs once
%% they do.
-module(node_config_check).

-export([check/2, check/3, known_words/0]).

-export_type([config/0]).

-type config() :: #{listeners := [agent_bridge:listener_opts()] | undefined,
                    pairings := [#{id := binary(), atom() => term()}],
                    mqtt_avatars := [mqtt_avatar:opts()],
                    wot_avatars := [wot_avatar:opts()],
                    http => evatar_web:opts()}.
%% `listeners' is `undefined' when the file has no listeners section: the
%% agent_bridge environment's listeners then stay. `http' is there only
%% when the file has an http section (the HTTP API's listener and operator
%% token, evatar_web).

-define(SECTIONS, [listeners, pairings, mqtt_avatars, wot_avatars, http]).
-define(HTTP_KEYS, [enabled, ip, port, operator_token_hash, token_file, max_body, max_clients,
                    header_timeout, things]).
-define(PAIRING_KEYS, [id, agent_credential, avatar_credential, identities, unlisted_ids]).
-define(IDENTITY_KEYS, [entity, role, credential, cert_sha256]).
-define(PAIRING_INT, [join_timeout, feedback_timeout, max_avatars, resume_timeout, dedup_window,
                      max_unacked_out]).
-define(AVATAR_KEYS, [entity_id, pairing, endpoints, credential, mqtt, discovery, description,
                      overrides, api_name, settle, discovery_wait, echo_timeout, retry,
                      timestamp_field, restart, birth]).
-define(WOT_KEYS, [entity_id, pairing, endpoints, credential, td, component, room, api_name, poll_ms,
                   allowed_hosts, max_size, max_affordances, thing_credentials, request_timeout,
                   longpoll_ms, retry_max_ms, max_body, restart]).
-define(WOT_POSITIVE, [max_size, max_affordances, request_timeout, longpoll_ms, retry_max_ms, max_body]).
-define(THING_CREDENTIAL_KEYS, [username, password, token]).
-define(MQTT_TEXT, [client_id, username, password]).
-define(MQTT_OTHER, [host, port, protocol, clean_start, session_expiry, keepalive, tls, reconnect,
                     inflight_window, retry_interval, connect_timeout, max_packet_size]).
-define(OVERRIDE_KEYS, [component, room, skip, parameters, services, consumes, feedback]).
-define(RESTART_KEYS, [min_ms, max_ms, stable_after_ms, loop_after]).
%% Lines an entry's mistakes take at most: a file of one broken entry
%% cannot flood the terminal.
-define(MAX_MISTAKES, 10).

%% @doc The words a file may use (its sections and keys, and the values
%% that are words), for node_config_file's atom check.
-spec known_words() -> [atom()].
known_words() ->
    ?SECTIONS ++ ?PAIRING_KEYS ++ ?IDENTITY_KEYS ++ ?PAIRING_INT ++ ?AVATAR_KEYS ++ ?MQTT_TEXT ++ ?MQTT_OTHER
        ++ ?OVERRIDE_KEYS ++ ?RESTART_KEYS ++ ?HTTP_KEYS ++ ?WOT_KEYS ++ ?THING_CREDENTIAL_KEYS
        ++ [pbkdf2_sha256, file]
        ++ [name, ip, acceptors, backlog, conn, homeassistant, zigbee2mqtt, v311, v5, min_ms,
            max_ms, true, false, none, infinity].

%% @doc Checks the sections; `Defaults' gives `listeners', the agent_bridge
%% environment's listeners, which an MQTT or WoT Avatar without `endpoints' joins
%% when the file declares none, and `dir', where relative description
%% and TD files are.
-spec check([node_config_file:section()], #{listeners := list(), dir => file:filename()}) ->
          {ok, config()} | {error, [binary()]}.
check(Sections, Defaults) ->
    check(Sections, Defaults, []).

%% @doc check/2, with the mistakes the reading found (`Earlier': its
%% unknown words, node_config_file:read/2), reported with the checks' in
%% the order of their lines.
-spec check([node_config_file:section()], #{listeners := list(), dir => file:filename()},
            [node_config_file:problem()]) -> {ok, config()} | {error, [binary()]}.
check(Sections, Defaults, Earlier) ->
    Problems0 = Earlier ++ [msg(L, "~ts: unknown section (the sections are listeners, pairings, mqtt_avatars, "
                        "wot_avatars, http)",
                     [Name])
                 || {Name, L, _} <- Sections, not lists:member(Name, ?SECTIONS)]
        ++ [msg(L, "~ts: the section appears a second time (write all its entries in one list)", [Name])
            || {Name, L, _} <- Sections -- lists:ukeysort(1, Sections)],
    {Listeners, P1} = section(listeners, Sections, fun listener/1),
    {Http, P5} = http(lists:keyfind(http, 1, Sections)),
    {Pairings, P2} = section(pairings, Sections, fun pairing/1),
    ListenerList = case lists:keymember(listeners, 1, Sections) of
                       true -> Listeners;
                       false -> maps:get(listeners, Defaults)
                   end,
    {Avatars, P3} = section(mqtt_avatars, Sections,
                            fun(E) -> avatar(E, declared_ids(Sections), Pairings,
                                             Defaults#{listeners => ListenerList})
                            end),
    {Things, P6} = section(wot_avatars, Sections,
                           fun(E) -> wot_avatar(E, declared_ids(Sections), Pairings,
                                                Defaults#{listeners => ListenerList})
                           end),
    P4 = duplicates(listeners, Sections, Listeners, fun listener_key/1)
        ++ duplicates(listeners, Sections, Listeners, fun(#{name := N}) -> {name, N};
                                                         (_) -> none
                                                      end)
        ++ duplicates(pairings, Sections, Pairings, fun(#{id := Id}) -> {id, Id} end)
        ++ duplicates(mqtt_avatars, Sections, Avatars, fun(#{entity_id := Id}) -> {entity_id, Id} end)
        ++ duplicates(wot_avatars, Sections, Things, fun(#{entity_id := Id}) -> {entity_id, Id} end)
        ++ shared_entity_ids(Sections, Avatars, Things),
    case Problems0 ++ P1 ++ P2 ++ P3 ++ P4 ++ P5 ++ P6 of
        [] ->
            {ok, Http#{listeners => case lists:keymember(listeners, 1, Sections) of
                                        true -> Listeners;
                                        false -> undefined
                                    end,
                       pairings => Pairings,
                       mqtt_avatars => Avatars,
                       wot_avatars => Things}};
        Problems ->
            {error, [M || {_, M} <- lists:keysort(1, Problems)]}
    end.

%% Every id the pairings section spells, good entry or not: an MQTT Avatar
%% naming a pairing with a mistake of its own is not "not declared".
declared_ids(Sections) ->
    case lists:keyfind(pairings, 1, Sections) of
        {_, _, Entries} when is_list(Entries) ->
            [B || {_, #{id := Id}} <- Entries, {ok, B} <- [text(Id)]];
        _ ->
            []
    end.

%% Every entry of a section goes through `Check'; the good ones are kept
%% (each with its line, for the duplicate check), the bad ones explained.
section(Name, Sections, Check) ->
    case lists:keyfind(Name, 1, Sections) of
        false ->
            {[], []};
        {_, L, {not_a_list, _}} ->
            {[], [msg(L, "~ts: the value must be a list [...] of entries", [Name])]};
        {_, _, Entries} ->
            Results = [{Line, N, E, Check(E)}
                       || {N, {Line, E}} <- lists:zip(lists:seq(1, length(Entries)), Entries)],
            {[V || {_, _, _, {ok, V}} <- Results],
             [msg(Line, "~ts entry ~b~ts: ~ts", [Name, N, label(E), M])
              || {Line, N, E, {error, Why}} <- Results, M <- lines(Why)]}
    end.

label(#{id := Id}) -> label_text(Id);
label(#{entity_id := Id}) -> label_text(Id);
label(#{name := Id}) -> label_text(Id);
label(#{entity := Id}) -> label_text(Id);
label(_) -> "".

label_text(T) ->
    case text(T) of
        {ok, B} -> io_lib:format(" (~ts)", [B]);
        error -> ""
    end.

duplicates(Name, Sections, Values, Key) ->
    Keys = [Key(V) || V <- Values],
    Dups = lists:usort([K || K <- Keys, K =/= none, length([K1 || K1 <- Keys, K1 =:= K]) > 1]),
    L = case lists:keyfind(Name, 1, Sections) of
            {_, Line, _} -> Line;
            false -> 1
        end,
    [msg(L, "~ts: ~ts appears more than once", [Name, describe_key(K)]) || K <- Dups].

describe_key({id, Id}) -> io_lib:format("id \"~ts\"", [Id]);
describe_key({entity_id, Id}) -> io_lib:format("entity_id \"~ts\"", [Id]);
describe_key({name, N}) -> io_lib:format("name ~0tp", [N]);
describe_key({address, Ip, Port}) -> io_lib:format("address ~ts port ~b", [inet:ntoa(Ip), Port]).

%% An MQTT and a WoT Avatar of one entity id would take each other's place
%% in their pairing (the second is refused, or resumes the first's
%% session).
shared_entity_ids(Sections, Avatars, Things) ->
    Mqtt = [Id || #{entity_id := Id} <- Avatars],
    L = case lists:keyfind(wot_avatars, 1, Sections) of
            {_, Line, _} -> Line;
            false -> 1
        end,
    [msg(L, "wot_avatars: entity_id \"~ts\" also names an MQTT Avatar (mqtt_avatars)", [Id])
     || Id <- lists:usort([Id || #{entity_id := Id} <- Things]), lists:member(Id, Mqtt)].

listener_key(#{port := Port} = L) when Port > 0 ->
    {address, maps:get(ip, L, {127, 0, 0, 1}), Port};
listener_key(_) ->
    none.

%% ---------------------------------------------------------------------------
%% Listeners: agent_bridge checks the options it takes.
%% ---------------------------------------------------------------------------

listener(E) when is_map(E) ->
    E1 = case maps:find(name, E) of
             {ok, N} -> case text(N) of
                            {ok, B} -> E#{name => B};
                            error -> E
                        end;
             error -> E
         end,
    case maps:find(ip, E1) of
        {ok, Ip} when is_list(Ip); is_binary(Ip) ->
            case inet:parse_strict_address(unicode:characters_to_list(Ip)) of
                {ok, Addr} -> check_listener(E1#{ip => Addr});
                {error, _} -> {error, io_lib:format("ip ~0tp is not an IP address", [Ip])}
            end;
        _ ->
            check_listener(E1)
    end;
listener(_) ->
    {error, "a listener is a map #{...}"}.

check_listener(E) ->
    case agent_bridge:check_listener(E) of
        ok -> {ok, E};
        {error, Why} -> {error, Why}
    end.

%% ---------------------------------------------------------------------------
%% The HTTP API (evatar_web checks the options it takes): one map,
%% {http, #{ip => "127.0.0.1", port => 7480, operator_token_hash => {...}}}.
%% ---------------------------------------------------------------------------

http(false) ->
    {#{}, []};
http({http, L, {not_a_list, E}}) when is_map(E) ->
    %% Each key on its own, so that every mistake is named: the keys this
    %% module reads (unknown ones, the text of token_file and ip, the two
    %% ways of giving a token), then evatar_web's own check of each key
    %% that read.
    {Read, Errors} = each([fun(X) -> unknown(X, ?HTTP_KEYS) end,
                           fun(X) -> texts([token_file], X) end,
                           %% evatar_web refuses both at its start (docs/api.md).
                           fun(#{operator_token_hash := H, token_file := F})
                                 when H =/= undefined, F =/= "", F =/= <<>> ->
                                   {error, "operator_token_hash and token_file: give one, not both"};
                              (X) -> {ok, X}
                           end,
                           fun(#{ip := Ip} = X) ->
                                   case text(Ip) of
                                       {ok, B} ->
                                           case inet:parse_strict_address(binary_to_list(B)) of
                                               {ok, Addr} -> {ok, X#{ip => Addr}};
                                               {error, _} -> {error, io_lib:format("ip \"~ts\" is not an "
                                                                                   "IP address", [B])}
                                           end;
                                       error ->
                                           {error, "ip must be an address in double quotes, for "
                                                   "example \"127.0.0.1\""}
                                   end;
                              (X) -> {ok, X}
                           end], E,
                          %% What a failed check read is not checked again.
                          #{1 => fun(X) -> maps:with(?HTTP_KEYS, X) end,
                            2 => fun(X) -> maps:remove(token_file, X) end,
                            4 => fun(X) -> maps:remove(ip, X) end}),
    Web = [io_lib:format("~0tp: ~ts", [K, Why])
           || {K, V} <- lists:sort(maps:to_list(Read)),
              {error, {_, Why}} <- [evatar_web:check_opts(#{K => V})]],
    case Errors ++ Web of
        [] -> {#{http => Read}, []};
        Whys -> {#{}, [msg(L, "http: ~ts", [M]) || M <- lines({mistakes, Whys})]}
    end;
http({http, L, _}) ->
    {#{}, [msg(L, "http: the value must be one map #{ip => \"127.0.0.1\", port => 7480, "
                  "operator_token_hash => {pbkdf2_sha256, ...}}", [])]}.

%% ---------------------------------------------------------------------------
%% Pairings: evatar checks the options it takes.
%% ---------------------------------------------------------------------------

pairing(E) when is_map(E) ->
    %% The keys this module reads, each on its own; then evatar's own check
    %% of the options, once per mistake it finds (pairing_opts/3).
    {P, Errors} = each([fun(P) -> chain([fun(P1) -> texts([id], P1) end,
                                          fun(#{id := Id} = P1) when Id =/= <<>> -> {ok, P1};
                                             (_) -> {error, "id (text, for example \"home\") is required"}
                                          end], P)
                        end,
                        fun(P) -> credentials([agent_credential, avatar_credential], P) end,
                        fun(#{identities := Is} = P) when is_list(Is) ->
                                Results = [{N, identity(I)} || {N, I} <- lists:zip(lists:seq(1, length(Is)), Is)],
                                case [{N, Why} || {N, {error, Why}} <- Results] of
                                    [] -> {ok, P#{identities := [I || {_, {ok, I}} <- Results]}};
                                    Bad -> {error, {mistakes,
                                                    [prefixed(io_lib:format("identities entry ~b~ts: ",
                                                                            [N, label(lists:nth(N, Is))]), Why)
                                                     || {N, Why} <- Bad]}}
                                end;
                           (#{identities := _}) ->
                                {error, "identities must be a list [#{entity => \"...\", role => agent, "
                                        "credential => \"...\"}, ...]"};
                           (P) -> {ok, P}
                        end], E,
                       #{1 => fun(X) -> maps:remove(id, X) end,
                         2 => fun(X) -> maps:without([agent_credential, avatar_credential], X) end,
                         3 => fun(X) -> maps:remove(identities, X) end}),
    %% Who may join cannot be judged without the keys that say it.
    Who = [agent_credential, avatar_credential, identities],
    Unjudged = [K || K <- Who, maps:is_key(K, E), not maps:is_key(K, P)],
    case Errors ++ pairing_opts(maps:remove(id, P), Unjudged, []) of
        [] -> {ok, P};
        [One] -> {error, One};
        Many -> {error, {mistakes, Many}}
    end;
pairing(_) ->
    {error, "a pairing is a map #{id => \"...\", agent_credential => \"...\", "
            "avatar_credential => \"...\"} or #{id => \"...\", identities => [...]}"}.

%% evatar's verdict on a pairing's options, every mistake: a key it
%% refuses is named and taken out, and the options checked again (at most
%% once per key). Which credentials are missing is not said when one of
%% them (or the identities) was taken out.
pairing_opts(Opts, Unjudged, Acc) ->
    case evatar:check_pairing_opts(Opts) of
        ok ->
            lists:reverse(Acc);
        {error, {bad_option, {missing, _}}} when Unjudged =/= [] ->
            lists:reverse(Acc);
        {error, {bad_option, {K, _} = Bad}} when is_atom(K), is_map_key(K, Opts) ->
            Unjudged1 = case lists:member(K, [agent_credential, avatar_credential, identities]) of
                            true -> [K | Unjudged];
                            false -> Unjudged
                        end,
            pairing_opts(maps:remove(K, Opts), Unjudged1, [iolist_to_binary(bad_pairing(Bad)) | Acc]);
        {error, {bad_option, Bad}} ->
            lists:reverse([iolist_to_binary(bad_pairing(Bad)) | Acc])
    end.

%% One device of a pairing's `identities': its text becomes binaries, its
%% role stays one of the two words; evatar checks the rest.
identity(I) when is_map(I) ->
    all_of([fun(X) -> texts([entity, cert_sha256], X) end,
            fun(X) -> credentials([credential], X) end], I);
identity(_) ->
    {error, "an identity is a map #{entity => \"...\", role => agent | avatar, "
            "credential => \"...\"} (or cert_sha256 => \"...\" instead of, or with, credential)"}.

%% A credential: text (not empty: there is no default secret), or its
%% hashed form as `bin/evatar hash_credential' prints it, which evatar
%% checks. Never echoed in a message.
credentials(Keys, M) ->
    case [K || K <- Keys, maps:is_key(K, M), credential(maps:get(K, M)) =:= error] of
        [] -> {ok, maps:map(fun(K, V) ->
                                    case lists:member(K, Keys) of
                                        true -> {ok, C} = credential(V), C;
                                        false -> V
                                    end
                            end, M)};
        Ks -> {error, io_lib:format("~ts must be a secret in double quotes, not empty, or its "
                                    "hashed form {pbkdf2_sha256, ...} (bin/evatar hash_credential)",
                                    [join(Ks)])}
    end.

credential({pbkdf2_sha256, _, _, _} = Hashed) ->
    {ok, Hashed};
credential(V) ->
    case text(V) of
        {ok, B} when B =/= <<>> -> {ok, B};
        _ -> error
    end.

%% evatar's verdict on a pairing's options, for a person.
bad_pairing({missing, Keys}) ->
    io_lib:format("~ts required (no default credentials: choose a secret), unless the pairing "
                  "lists identities", [join(Keys)]);
bad_pairing({identities, duplicate_entity}) ->
    "identities: an entity appears more than once";
bad_pairing({identity, E, {unknown_keys, Keys}}) ->
    io_lib:format("identity \"~ts\": unknown key ~ts (known: entity, role, credential, cert_sha256)",
                  [E, join([io_lib:format("~0tp", [K]) || K <- Keys])]);
bad_pairing({identity, E, no_credential_or_certificate}) ->
    io_lib:format("identity \"~ts\": credential or cert_sha256 required", [E]);
bad_pairing({identity, E, {cert_sha256, F}}) when is_binary(F) ->
    io_lib:format("identity \"~ts\": cert_sha256 \"~ts\" is not a SHA-256 fingerprint (64 hex digits, "
                  "colons allowed: openssl x509 -noout -fingerprint -sha256)", [E, F]);
bad_pairing({{identity, E}, _Credential}) ->
    io_lib:format("identity \"~ts\": credential is not a hashed credential as bin/evatar "
                  "hash_credential prints it", [E]);
bad_pairing({identity, _}) ->
    "an identity needs entity (text, not empty) and role (agent or avatar)";
bad_pairing({unlisted_ids, _}) ->
    "unlisted_ids must be refuse or role_credential";
bad_pairing({K, _Credential}) when K =:= agent_credential; K =:= avatar_credential ->
    io_lib:format("~ts is not a hashed credential as bin/evatar hash_credential prints it", [K]);
bad_pairing({K, V}) when is_atom(K) ->
    case evatar:pairing_option_ranges() of
        #{K := {Min, Max}} ->
            io_lib:format("~ts ~0tp is not accepted: an integer from ~b to ~b~ts", [K, V, Min, Max,
                          case lists:member(K, [join_timeout, feedback_timeout, resume_timeout]) of
                              true -> " (milliseconds)";
                              false -> ""
                          end]);
        #{} ->
            io_lib:format("~ts ~0tp is not accepted", [K, V])
    end;
bad_pairing(Bad) ->
    io_lib:format("bad option ~0tp", [Bad]).

%% ---------------------------------------------------------------------------
%% MQTT Avatars
%% ---------------------------------------------------------------------------

avatar(E, PairingIds, Pairings, #{listeners := Listeners} = Defaults) when is_map(E) ->
    %% Each key on its own: every mistake at once.
    Keys = [fun(A) -> unknown(A, ?AVATAR_KEYS) end,
            fun(A) -> texts([entity_id, pairing, credential, api_name, timestamp_field], A) end,
            fun(A) -> required([entity_id, pairing, mqtt], A) end,
            fun(A) -> integers([settle, discovery_wait, echo_timeout], 0, A) end,
            fun(A) -> integers([retry], 1, A) end,
            fun(A) -> submap(mqtt, fun mqtt/1, A) end,
            fun(A) -> submap(discovery, fun discovery/1, A) end,
            fun(A) -> submap(birth, fun birth/1, A) end,
            fun(A) -> submap(overrides, fun overrides/1, A) end,
            fun(A) -> submap(restart, fun restart/1, A) end,
            fun(A) -> description(A, maps:get(dir, Defaults, ".")) end],
    %% Then, once the keys read: the options as mqtt_avatar takes them
    %% (the description file and its BIL), and the pairing it joins.
    stages([Keys, joining(fun mqtt_avatar:check_opts/1, PairingIds, Pairings, Listeners)], E);
avatar(_, _, _, _Defaults) ->
    {error, "an MQTT Avatar is a map #{entity_id => \"...\", pairing => \"...\", mqtt => #{...}}"}.

%% ---------------------------------------------------------------------------
%% WoT Avatars: a Thing (its TD at a URL or in a file) as an Avatar of a
%% pairing; wot_avatar checks the options it takes.
%% ---------------------------------------------------------------------------

wot_avatar(E, PairingIds, Pairings, #{listeners := Listeners} = Defaults) when is_map(E) ->
    Keys = [fun(A) -> unknown(A, ?WOT_KEYS) end,
            fun(A) -> texts([entity_id, pairing, credential, component, room, api_name], A) end,
            fun(A) -> required([entity_id, pairing, td], A) end,
            fun(A) -> td(A, maps:get(dir, Defaults, ".")) end,
            fun(A) -> integers([poll_ms], 0, A) end,
            fun(A) -> integers(?WOT_POSITIVE, 1, A) end,
            fun(A) -> allowed_hosts(A) end,
            fun(A) -> submap(thing_credentials, fun thing_credentials/1, A) end,
            fun(A) -> submap(restart, fun restart/1, A) end],
    %% Then, once the keys read: the options as wot_avatar takes them (its
    %% limits) and the pairing it joins; wot_avatar's check sees a stand-in
    %% `evatar', which evatar_opts/3 judges.
    Check = fun(A) ->
                    wot_avatar:check_opts((maps:without([pairing, endpoints, credential], A))#{
                                            evatar => #{endpoints => [{"localhost", 1}], pairing => <<"p">>}})
            end,
    stages([Keys, joining(Check, PairingIds, Pairings, Listeners)], E);
wot_avatar(_, _, _, _Defaults) ->
    {error, "a WoT Avatar is a map #{entity_id => \"...\", pairing => \"...\", "
            "td => \"http://...\" or {file, \"...\"}}"}.

%% The TD: an http(s) URL, or a file, relative paths from the
%% configuration file's directory.
td(#{td := {file, F}} = A, Dir) ->
    case text(F) of
        {ok, B} when B =/= <<>> ->
            {ok, A#{td => {file, filename:absname(unicode:characters_to_list(B), Dir)}}};
        _ ->
            {error, "td: {file, \"...\"} must name a file (text in double quotes)"}
    end;
td(#{td := T} = A, _Dir) ->
    case text(T) of
        {ok, <<"http://", _/binary>> = B} -> {ok, A#{td => B}};
        {ok, <<"https://", _/binary>> = B} -> {ok, A#{td => B}};
        _ -> {error, "td must be the TD's http(s) URL in double quotes, or {file, \"lamp.td.json\"} "
                     "(relative to this file's directory)"}
    end;
td(A, _Dir) ->
    {ok, A}.

allowed_hosts(#{allowed_hosts := Hs} = A) when is_list(Hs) ->
    Texts = [text(H) || H <- Hs],
    case [B || {ok, B} <- Texts, B =/= <<>>] of
        Bs when length(Bs) =:= length(Hs) -> {ok, A#{allowed_hosts => Bs}};
        _ -> {error, "allowed_hosts must be a list of \"host\" or \"host:port\""}
    end;
allowed_hosts(#{allowed_hosts := _}) ->
    {error, "allowed_hosts must be a list of \"host\" or \"host:port\""};
allowed_hosts(A) ->
    {ok, A}.

%% What the Thing's forms ask for: basic (username and password) or bearer
%% (token). Never echoed in a message.
thing_credentials(C) ->
    chain([fun(X) -> unknown(X, ?THING_CREDENTIAL_KEYS) end,
           fun(X) -> texts(?THING_CREDENTIAL_KEYS, X) end,
           fun(#{token := _} = X) when map_size(X) =:= 1 -> {ok, X};
              (#{username := _, password := _} = X) when map_size(X) =:= 2 -> {ok, X};
              (_) -> {error, "give #{token => \"...\"} (bearer) or #{username => \"...\", "
                             "password => \"...\"} (basic)"}
           end], C).

%% The checks of an Avatar whose keys read: the options as its app takes
%% them (`Check', every mistake), and the pairing it joins.
joining(Check, PairingIds, Pairings, Listeners) ->
    [fun(A) -> case Check(A) of
                   ok -> {ok, A};
                   {error, Ps} -> {error, {mistakes, [M || #{message := M} <- Ps]}}
               end
     end,
     fun(A) -> chain([fun(A1) -> declared(A1, PairingIds) end,
                      fun(A1) -> evatar_opts(A1, Pairings, Listeners) end], A)
     end].

declared(#{pairing := P} = A, Ids) ->
    case lists:member(P, Ids) of
        true -> {ok, A};
        false -> {error, io_lib:format("pairing \"~ts\" is not declared in the pairings section", [P])}
    end.

%% `evatar' as mqtt_avatar takes it: the pairing, its avatar credential
%% (unless given), and this node's own listener (unless endpoints are given).
evatar_opts(#{pairing := P} = A, Pairings, Listeners) ->
    case avatar_credential(A, [X || #{id := Id} = X <- Pairings, Id =:= P]) of
        {ok, Credential} ->
            case endpoints(maps:get(endpoints, A, local), Listeners) of
                {ok, Endpoints} ->
                    {ok, (maps:without([pairing, endpoints, credential], A))#{
                           evatar => #{pairing => P, credential => Credential,
                                       endpoints => Endpoints}}};
                {error, _} = Error ->
                    Error
            end;
        {error, _} = Error ->
            Error
    end.

%% The credential the Avatar joins with: its own `credential', else the
%% plain one the pairing lets it join with (its identity's, or the avatar
%% role's). An Avatar its pairing would refuse is a mistake of the file.
avatar_credential(#{pairing := P}, []) ->
    {error, io_lib:format("pairing \"~ts\" has a mistake (see its entry)", [P])};
avatar_credential(#{entity_id := E, pairing := P} = A, [Pairing]) ->
    Identities = maps:get(identities, Pairing, []),
    Own = maps:find(credential, A),
    case [I || #{entity := E1} = I <- Identities, E1 =:= E] of
        [#{role := avatar} = I] ->
            plain(Own, maps:find(credential, I),
                  io_lib:format("the identity of \"~ts\" in pairing \"~ts\" has no plain credential",
                                [E, P]));
        [_] ->
            {error, io_lib:format("pairing \"~ts\" lists \"~ts\" in its identities with role agent: "
                                  "an Avatar cannot join as it", [P, E])};
        [] when Identities =/= [] ->
            case maps:get(unlisted_ids, Pairing, refuse) of
                role_credential ->
                    role_credential(Own, Pairing);
                refuse ->
                    {error, io_lib:format("pairing \"~ts\" would refuse it: \"~ts\" is not in its "
                                          "identities and it has no unlisted_ids => role_credential",
                                          [P, E])}
            end;
        [] ->
            role_credential(Own, Pairing)
    end.

role_credential(Own, #{id := P} = Pairing) ->
    plain(Own, maps:find(avatar_credential, Pairing),
          io_lib:format("pairing \"~ts\" has no plain avatar_credential", [P])).

plain({ok, C}, _, _) -> {ok, C};
plain(error, {ok, C}, _) when is_binary(C) -> {ok, C};
plain(error, _, Why) -> {error, ["credential => \"...\" required: ", Why]}.

endpoints(local, [L | _]) ->
    case maps:get(port, L, 7400) of
        0 -> {error, "endpoints are required: this node's first listener has port 0 (a port picked "
                     "at start)"};
        Port -> {ok, [{loopback(maps:get(ip, L, {127, 0, 0, 1})), Port}]}
    end;
endpoints(local, []) ->
    {error, "endpoints are required: this node has no listener"};
endpoints(List, _) when is_list(List), List =/= [] ->
    Eps = [endpoint(E) || E <- List],
    case [E || {error, E} <- Eps] of
        [] -> {ok, [Ep || {ok, Ep} <- Eps]};
        [Bad | _] -> {error, io_lib:format("endpoint ~0tp is not {\"host\", Port}", [Bad])}
    end;
endpoints(Other, _) ->
    {error, io_lib:format("endpoints ~0tp is not a list of {\"host\", Port}", [Other])}.

endpoint({Host, Port} = E) when is_integer(Port), Port > 0, Port < 65536 ->
    case Host of
        _ when is_tuple(Host) ->
            case inet:is_ip_address(Host) of
                true -> {ok, E};
                false -> {error, E}
            end;
        _ ->
            case text(Host) of
                {ok, B} -> {ok, {binary_to_list(B), Port}};
                error -> {error, E}
            end
    end;
endpoint(E) ->
    {error, E}.

loopback({0, 0, 0, 0}) -> {127, 0, 0, 1};
loopback({0, 0, 0, 0, 0, 0, 0, 0}) -> {0, 0, 0, 0, 0, 0, 0, 1};
loopback(Ip) -> Ip.

mqtt(M) ->
    all_of([fun(X) -> unknown(X, ?MQTT_TEXT ++ ?MQTT_OTHER) end,
           fun(X) -> texts(?MQTT_TEXT, X) end,
           fun(X) -> required([host, port], X) end,
           fun(#{host := H} = X) ->
                   case H of
                       _ when is_tuple(H) ->
                           case inet:is_ip_address(H) of
                               true -> {ok, X};
                               false -> {error, io_lib:format("host ~0tp is not an address", [H])}
                           end;
                       _ ->
                           case text(H) of
                               {ok, B} -> {ok, X#{host => binary_to_list(B)}};
                               error -> {error, "host must be text, for example \"localhost\""}
                           end
                   end;
              (X) -> {ok, X}
           end,
           fun(X) -> integers([port], 1, X) end,
           fun(X) -> integers([session_expiry, keepalive], 0, X) end,
           fun(X) -> integers([inflight_window, retry_interval, connect_timeout, max_packet_size], 1, X) end,
           fun(X) -> one_of(protocol, [v311, v5], X) end,
           fun(X) -> one_of(clean_start, [true, false], X) end,
           fun(#{tls := T} = X) when T =:= false; is_list(T) -> {ok, X};
              (#{tls := _}) -> {error, "tls must be false or a list of TLS client options"};
              (X) -> {ok, X}
           end,
           fun(#{reconnect := false} = X) -> {ok, X};
              (#{reconnect := R} = X) when is_map(R) ->
                   case all_of([fun(Y) -> unknown(Y, [min_ms, max_ms]) end,
                                fun(Y) -> integers([min_ms, max_ms], 1, Y) end], R) of
                       {ok, _} -> {ok, X};
                       {error, W} -> {error, prefixed("reconnect: ", W)}
                   end;
              (#{reconnect := _}) -> {error, "reconnect must be false or #{min_ms => ..., max_ms => ...}"};
              (X) -> {ok, X}
           end], M).

discovery(false) ->
    {ok, false};
discovery(D) when is_map(D) ->
    all_of([fun(X) -> unknown(X, [homeassistant, zigbee2mqtt, max_config_size, max_device_list_size]) end,
           fun(X) -> integers([max_config_size], 1, X) end,
           fun(#{max_device_list_size := N} = X) ->
                   {_Default, Limit} = mqtt_avatar:discovery_max_device_list(),
                   case is_integer(N) andalso N >= 1 andalso N =< Limit of
                       true -> {ok, X};
                       false -> {error, io_lib:format("max_device_list_size must be an integer "
                                                      "from 1 to ~b (bytes)", [Limit])}
                   end;
              (X) -> {ok, X}
           end,
           fun(X) ->
                   lists:foldl(fun(_K, {error, _} = Err) -> Err;
                                  (K, {ok, Acc}) ->
                                       case maps:find(K, Acc) of
                                           {ok, false} -> {ok, Acc};
                                           {ok, V} ->
                                               case text(V) of
                                                   {ok, B} when B =/= <<>> -> {ok, Acc#{K => B}};
                                                   _ -> {error, io_lib:format(
                                                                  "~ts must be a topic prefix (text) or false",
                                                                  [K])}
                                               end;
                                           error -> {ok, Acc}
                                       end
                               end, {ok, X}, [homeassistant, zigbee2mqtt])
           end], D);
discovery(_) ->
    {error, "must be false or #{homeassistant => \"homeassistant\", zigbee2mqtt => \"zigbee2mqtt\"}"}.

birth(false) ->
    {ok, false};
birth(B) ->
    all_of([fun(X) -> unknown(X, [topic, payload]) end,
            fun(X) -> chain([fun(Y) -> texts([topic, payload], Y) end,
                             fun(#{topic := <<>>}) -> {error, "topic must not be empty"};
                                (Y) -> {ok, Y}
                             end], X)
            end], B).

overrides(O) ->
    Results = [{K, text(K), override(V)} || {K, V} <- maps:to_list(O)],
    case [{K, W} || {K, _, {error, W}} <- Results] ++ [{K, "the key must be text"}
                                                        || {K, error, _} <- Results] of
        [] -> {ok, maps:from_list([{B, V} || {_, {ok, B}, {ok, V}} <- Results])};
        Bad -> {error, {mistakes, [prefixed(io_lib:format("override ~0tp: ", [K]), W)
                                   || {K, W} <- Bad]}}
    end.

override(V) when is_map(V) ->
    all_of([fun(X) -> unknown(X, ?OVERRIDE_KEYS) end,
           fun(X) -> texts([component, room], X) end,
           fun(X) -> one_of(skip, [true, false], X) end,
           fun(#{feedback := none} = X) -> {ok, X};
              (X) -> texts([feedback], X)
           end,
           fun(X) -> case maps:find(parameters, X) of
                         error -> {ok, X};
                         {ok, Ps} -> parameters(Ps, X)
                     end
           end,
           fun(X) -> case [K || K <- [services, consumes], maps:is_key(K, X),
                                not is_list(maps:get(K, X))] of
                         [] -> {ok, X};
                         [K | _] -> {error, io_lib:format("~ts must be a list", [K])}
                     end
           end], V);
override(_) ->
    {error, "an override is a map #{room => \"...\", ...}"}.

parameters(Ps, X) when is_list(Ps) ->
    Pairs = [{text(N), text(V)} || {N, V} <- Ps],
    case length(Pairs) =:= length(Ps) andalso [P || {A, B} = P <- Pairs, A =:= error orelse B =:= error] of
        [] -> {ok, X#{parameters => [{N, V} || {{ok, N}, {ok, V}} <- Pairs]}};
        _ -> {error, "parameters must be a list of {\"Name\", \"value\"}"}
    end;
parameters(_, _) ->
    {error, "parameters must be a list of {\"Name\", \"value\"}"}.

restart(R) ->
    all_of([fun(X) -> unknown(X, ?RESTART_KEYS) end,
           fun(X) -> integers(?RESTART_KEYS, 1, X) end], R).

%% A hand-written description is a file (BIL XML, as printed and edited),
%% relative paths from the configuration file's directory (node_config
%% resolves them before).
description(#{description := D} = A, Dir) ->
    case text(D) of
        {ok, B} -> {ok, A#{description => {file, filename:absname(unicode:characters_to_list(B), Dir)}}};
        error -> {error, "description must be the name of a BIL XML file (text)"}
    end;
description(A, _Dir) ->
    {ok, A}.

%% ---------------------------------------------------------------------------
%% Small checks; each returns {ok, Map} or {error, Why}.
%% ---------------------------------------------------------------------------

%% Checks that depend on each other: the first mistake stops.
chain([], V) -> {ok, V};
chain([F | Fs], V) ->
    case F(V) of
        {ok, V1} -> chain(Fs, V1);
        {error, _} = Error -> Error
    end.

%% Independent checks (each reads and changes its own keys): every one
%% runs, each on the value as the good ones before left it, and every
%% mistake is reported (`{mistakes, [Why]}' when there are several).
all_of(Checks, V) ->
    {V1, Errors} = lists:foldl(fun(F, {Acc, Es}) ->
                                       case F(Acc) of
                                           {ok, Acc1} -> {Acc1, Es};
                                           {error, Why} -> {Acc, Es ++ lines(Why)}
                                       end
                               end, {V, []}, Checks),
    case Errors of
        [] -> {ok, V1};
        [One] -> {error, One};
        Many -> {error, {mistakes, Many}}
    end.

%% Independent checks, all run in turn on the value as the ones before
%% left it; when check N fails, `Drop' (a map from N) may take out of the
%% value what it read, so that later checks do not judge it again.
%% Returns the value and every mistake.
each(Checks, V, Drop) ->
    {V1, Errors, _} = lists:foldl(
                        fun(F, {Acc, Es, N}) ->
                                case F(Acc) of
                                    {ok, Acc1} ->
                                        {Acc1, Es, N + 1};
                                    {error, Why} ->
                                        Rest = (maps:get(N, Drop, fun(X) -> X end))(Acc),
                                        {Rest, Es ++ lines(Why), N + 1}
                                end
                        end, {V, [], 1}, Checks),
    {V1, Errors}.

%% Groups of independent checks, each group run once the one before
%% passed (it needs what they check).
stages(Groups, V) ->
    chain([fun(X) -> all_of(G, X) end || G <- Groups], V).

%% The lines of a mistake (several for `{mistakes, _}'), at most
%% ?MAX_MISTAKES.
lines({mistakes, Ws}) when length(Ws) > ?MAX_MISTAKES ->
    lists:sublist(Ws, ?MAX_MISTAKES - 1)
        ++ [io_lib:format("and ~b more mistakes", [length(Ws) - ?MAX_MISTAKES + 1])];
lines({mistakes, Ws}) -> Ws;
lines(Why) -> [Why].

%% A mistake of a part (`mqtt: ...'), each of its lines prefixed.
prefixed(Prefix, {mistakes, Ws}) -> {mistakes, [[Prefix, W] || W <- Ws]};
prefixed(Prefix, Why) -> [Prefix, Why].

submap(Key, Check, A) ->
    case maps:find(Key, A) of
        error -> {ok, A};
        {ok, V} when is_map(V); V =:= false ->
            case Check(V) of
                {ok, V1} -> {ok, A#{Key => V1}};
                {error, Why} -> {error, prefixed([atom_to_list(Key), ": "], Why)}
            end;
        {ok, _} -> {error, io_lib:format("~ts must be a map #{...}", [Key])}
    end.

unknown(M, Keys) when is_map(M) ->
    case [K || K <- maps:keys(M), not lists:member(K, Keys)] of
        [] -> {ok, M};
        Bad -> {error, io_lib:format("unknown key ~ts (known: ~ts)",
                                     [join([io_lib:format("~0tp", [K]) || K <- Bad]), join(Keys)])}
    end.

required(Keys, M) ->
    case [K || K <- Keys, not maps:is_key(K, M)] of
        [] -> {ok, M};
        Missing -> {error, io_lib:format("~ts required", [join(Missing)])}
    end.

texts(Keys, M) ->
    all_of([fun(Acc) ->
                    case maps:find(K, Acc) of
                        error -> {ok, Acc};
                        {ok, V} ->
                            case text(V) of
                                {ok, B} -> {ok, Acc#{K => B}};
                                error -> {error, io_lib:format("~ts must be text in double quotes",
                                                               [K])}
                            end
                    end
            end || K <- Keys], M).

integers(Keys, Min, M) ->
    case [K || K <- Keys, maps:is_key(K, M),
               not (is_integer(maps:get(K, M)) andalso maps:get(K, M) >= Min)] of
        [] -> {ok, M};
        [K] -> {error, io_lib:format("~ts must be an integer of at least ~b", [K, Min])};
        Ks -> {error, io_lib:format("~ts must be integers of at least ~b", [join(Ks), Min])}
    end.

one_of(Key, Allowed, M) ->
    case maps:find(Key, M) of
        error -> {ok, M};
        {ok, V} ->
            case lists:member(V, Allowed) of
                true -> {ok, M};
                false -> {error, io_lib:format("~ts must be one of ~ts", [Key, join(Allowed)])}
            end
    end.

%% Text: "..." in the file (a list of characters) or <<"...">>.
text(B) when is_binary(B) ->
    case unicode:characters_to_binary(B) of
        B -> {ok, B};
        _ -> error
    end;
text(L) when is_list(L) ->
    case io_lib:printable_unicode_list(L) of
        true -> {ok, unicode:characters_to_binary(L)};
        false -> error
    end;
text(_) ->
    error.

join(Items) ->
    lists:join(", ", [case I of
                          A when is_atom(A) -> atom_to_list(A);
                          S -> S
                      end || I <- Items]).

msg(Line, Format, Args) ->
    {Line, iolist_to_binary(io_lib:format("line ~b: " ++ Format, [Line | Args]))}.
