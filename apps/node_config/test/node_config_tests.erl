%% EUnit: the node configuration file's reader (node_config_file) and
%% checks (node_config_check), through node_config:load/1 on real files.
-module(node_config_tests).

-include_lib("eunit/include/eunit.hrl").

-define(PAIRING, "{pairings, [#{id => \"home\", agent_credential => \"va-secret\", "
                 "avatar_credential => \"av-secret\"}]}.\n").
-define(AVATAR(Extra), "{mqtt_avatars, [#{entity_id => \"house\", pairing => \"home\", "
                       "mqtt => #{host => \"localhost\", port => 1883}" Extra "}]}.\n").

load(Text) ->
    File = filename:join(dir(), "evatar.config"),
    ok = file:write_file(File, Text),
    node_config:load(File).

dir() ->
    Dir = filename:join(["/tmp", "node_config_tests." ++ os:getpid()]),
    ok = filelib:ensure_dir(filename:join(Dir, "x")),
    Dir.

%% The problems of a refused file, each without its "line N: " prefix.
problems(Text) ->
    {error, {bad_config, _, Ps}} = load(Text),
    [P || P <- Ps].

has(Text, Expected) ->
    Ps = problems(Text),
    ?assert(lists:any(fun(P) -> binary:match(P, list_to_binary(Expected)) =/= nomatch end, Ps),
            {Expected, Ps}).

%% ---------------------------------------------------------------------------
%% Accepted files
%% ---------------------------------------------------------------------------

empty_file_declares_nothing_test() ->
    {ok, #{listeners := undefined, pairings := [], mqtt_avatars := []}} =
        load("%% nothing here\n").

full_file_is_translated_test() ->
    {ok, #{listeners := [L], pairings := [P], mqtt_avatars := [A]}} =
        load("{listeners, [#{name => \"main\", ip => \"0.0.0.0\", port => 7411, "
             "conn => #{heartbeat => 200}}]}.\n" ?PAIRING
             ?AVATAR(", discovery => #{zigbee2mqtt => false}, "
                     "overrides => #{\"ha:1\" => #{room => \"hall\", feedback => none, "
                     "parameters => [{\"Light\", \"yes\"}]}}, restart => #{min_ms => 10}")),
    #{name := <<"main">>, ip := {0, 0, 0, 0}, port := 7411, conn := #{heartbeat := 200}} = L,
    #{id := <<"home">>, agent_credential := <<"va-secret">>, avatar_credential := <<"av-secret">>} = P,
    %% Text became binaries (the host stays a string, as inet takes it);
    %% the Avatar joins its pairing with the pairing's avatar credential at
    %% this node's listener, reached on the loopback address.
    #{entity_id := <<"house">>, mqtt := #{host := "localhost", port := 1883},
      evatar := #{pairing := <<"home">>, credential := <<"av-secret">>,
                  endpoints := [{{127, 0, 0, 1}, 7411}]},
      discovery := #{zigbee2mqtt := false},
      overrides := #{<<"ha:1">> := #{room := <<"hall">>, feedback := none,
                                     parameters := [{<<"Light">>, <<"yes">>}]}},
      restart := #{min_ms := 10}} = A,
    false = maps:is_key(pairing, A).

every_listener_option_of_the_bridge_test() ->
    %% Options the bridge checks itself (limits included) pass through.
    {ok, #{listeners := [#{max_connections := 10, conn := #{linger := 0}}]}} =
        load("{listeners, [#{port => 7411, max_connections => 10, conn => #{linger => 0}}]}."),
    has("{listeners, [#{port => 7411, max_connections => 0}]}.", "max_connections must be"),
    %% TLS: the bridge reads the certificate files when it checks.
    has("{listeners, [#{port => 7443, tls => #{certfile => \"/nonexistent/c.pem\", "
        "keyfile => \"/nonexistent/k.pem\"}}]}.",
        "listeners entry 1: tls certfile /nonexistent/c.pem cannot be read").

explicit_endpoints_and_credential_test() ->
    {ok, #{mqtt_avatars := [#{evatar := E}]}} =
        load(?PAIRING ?AVATAR(", endpoints => [{\"evatar2.local\", 7400}, {{10,0,0,2}, 7401}], "
                              "credential => \"other\"")),
    #{endpoints := [{"evatar2.local", 7400}, {{10, 0, 0, 2}, 7401}], credential := <<"other">>} = E.

binaries_are_text_too_test() ->
    {ok, #{pairings := [#{id := <<"home">>}]}} =
        load("{pairings, [#{id => <<\"home\">>, agent_credential => <<\"a\">>, "
             "avatar_credential => <<\"b\">>}]}.").

shipped_example_is_inert_and_valid_when_uncommented_test() ->
    Example = filename:join([code:lib_dir(node_config), "..", "..", "..", "..", "config",
                             "evatar.config"]),
    {ok, Bin} = file:read_file(Example),
    {ok, #{listeners := undefined, pairings := [], mqtt_avatars := [], wot_avatars := []}} = load(Bin),
    {ok, #{listeners := [_], pairings := [_], mqtt_avatars := [_], wot_avatars := [_],
           http := #{ip := {127, 0, 0, 1}, port := 7480}}} = load(uncomment(Bin)).

%% The http section: the address becomes a tuple, a hashed operator token
%% is checked by evatar_web, and each mistake names the key.
http_section_test() ->
    Hash = node_config:hashed_credential(<<"operator-token">>),
    {ok, #{http := #{ip := {0, 0, 0, 0}, port := 0, operator_token_hash := {pbkdf2_sha256, _, _, _},
                     enabled := true}}} =
        load(["{http, #{ip => \"0.0.0.0\", port => 0, enabled => true, operator_token_hash => ",
              Hash, "}}.\n"]),
    {ok, Config} = load("%% none\n"),
    false = maps:is_key(http, Config),
    has("{http, #{ip => \"localhost:80\"}}.\n", "http: ip \"localhost:80\" is not an IP address"),
    has("{http, #{port => 70000}}.\n", "http: port: must be a port number"),
    has("{http, #{port => 7480, colour => 1}}.\n", "http: unknown key colour"),
    has("{http, #{operator_token_hash => \"plain\"}}.\n",
        "http: operator_token_hash: must be a hashed credential"),
    has("{http, #{enabled => yes}}.\n", "http: enabled: must be true or false"),
    {ok, #{http := #{header_timeout := 2000}}} = load("{http, #{header_timeout => 2000}}.\n"),
    has("{http, #{header_timeout => 0}}.\n", "http: header_timeout: must be a time in milliseconds"),
    has("{http, [#{port => 1}]}.\n", "http: the value must be one map").

%% The http section's WoT consumers (docs/wot.md) are read and checked by
%% evatar_web; a pairing named twice is named as the mistake.
http_things_test() ->
    {ok, #{http := #{things := [#{pairing := "home", credential := "agent-secret",
                                   entity_id := "wot"}]}}} =
        load("{http, #{things => [#{pairing => \"home\", credential => \"agent-secret\", "
             "entity_id => \"wot\"}]}}.\n"),
    has("{http, #{things => [#{pairing => \"p\", credential => \"c\"}, "
        "#{pairing => \"p\", credential => \"d\"}]}}.\n",
        "http: things: names a pairing more than once"),
    has("{http, #{things => [#{pairing => \"p\"}]}}.\n", "http: things: must be a list of").

%% A WoT Avatar: text becomes binaries, a TD file is found from the
%% file's directory, and the Avatar joins its pairing with the pairing's
%% avatar credential at this node's listener, as an MQTT Avatar does.
wot_avatars_are_translated_test() ->
    {ok, #{wot_avatars := [Url, File]}} =
        load("{listeners, [#{name => \"main\", ip => \"0.0.0.0\", port => 7411}]}.\n" ?PAIRING
             "{wot_avatars, [#{entity_id => \"wot-lamp\", pairing => \"home\",\n"
             "                 td => \"http://192.168.1.20:8080/lamp\", room => \"bedroom\",\n"
             "                 poll_ms => 0, thing_credentials => #{token => \"t\"},\n"
             "                 restart => #{min_ms => 10}},\n"
             "               #{entity_id => \"wot-plug\", pairing => \"home\", credential => \"own\",\n"
             "                 td => {file, \"things/plug.td.json\"}, allowed_hosts => [\"plug.local:80\"],\n"
             "                 endpoints => [{\"evatar2.local\", 7400}]}]}.\n"),
    #{entity_id := <<"wot-lamp">>, td := <<"http://192.168.1.20:8080/lamp">>, room := <<"bedroom">>,
      poll_ms := 0, thing_credentials := #{token := <<"t">>}, restart := #{min_ms := 10},
      evatar := #{pairing := <<"home">>, credential := <<"av-secret">>,
                  endpoints := [{{127, 0, 0, 1}, 7411}]}} = Url,
    false = maps:is_key(pairing, Url),
    PlugFile = filename:join([dir(), "things", "plug.td.json"]),
    #{td := {file, PlugFile}, allowed_hosts := [<<"plug.local:80">>],
      evatar := #{credential := <<"own">>, endpoints := [{"evatar2.local", 7400}]}} = File,
    %% wot_avatar takes them as they are.
    ok = wot_avatar:check_opts(Url),
    ok = wot_avatar:check_opts(File).

%% Every independent mistake of a WoT Avatar at once; what needs the keys
%% right (the pairing, wot_avatar's own limits) once they are.
every_mistake_of_a_wot_avatar_test() ->
    Ps = problems(?PAIRING "{wot_avatars, [#{entity_id => \"lamp\", pairing => \"home\",\n"
                  "  td => \"ftp://lamp\", poll_ms => -1, timeout => 5, allowed_hosts => \"lamp.local\",\n"
                  "  thing_credentials => #{token => \"t\", user => \"me\"}, max_body => 0}]}.\n"),
    ?assertEqual([<<"line 2: wot_avatars entry 1 (lamp): unknown key timeout (known: entity_id, "
                    "pairing, endpoints, credential, td, component, room, api_name, poll_ms, "
                    "allowed_hosts, max_size, max_affordances, thing_credentials, request_timeout, "
                    "longpoll_ms, retry_max_ms, max_body, restart)">>,
                  <<"line 2: wot_avatars entry 1 (lamp): td must be the TD's http(s) URL in double "
                    "quotes, or {file, \"lamp.td.json\"} (relative to this file's directory)">>,
                  <<"line 2: wot_avatars entry 1 (lamp): poll_ms must be an integer of at least 0">>,
                  <<"line 2: wot_avatars entry 1 (lamp): max_body must be an integer of at least 1">>,
                  <<"line 2: wot_avatars entry 1 (lamp): allowed_hosts must be a list of \"host\" or "
                    "\"host:port\"">>,
                  <<"line 2: wot_avatars entry 1 (lamp): thing_credentials: unknown key user (known: "
                    "username, password, token)">>],
                 Ps),
    %% Required keys; the credentials never echoed.
    [<<"line 2: wot_avatars entry 1: entity_id, td required">>,
     <<"line 2: wot_avatars entry 1: thing_credentials: give #{token => ", Rest/binary>>] =
        problems(?PAIRING "{wot_avatars, [#{pairing => \"home\",\n"
                 "  thing_credentials => #{username => \"me\", token => \"hidden-secret\"}}]}.\n"),
    nomatch = binary:match(Rest, <<"hidden-secret">>),
    %% Once the keys read: an undeclared pairing and wot_avatar's limit,
    %% together.
    [<<"line 2: wot_avatars entry 1 (lamp): max_size must be a positive integer, at most 1048576">>,
     <<"line 2: wot_avatars entry 1 (lamp): pairing \"flat\" is not declared", _/binary>>] =
        problems(?PAIRING "{wot_avatars, [#{entity_id => \"lamp\", pairing => \"flat\",\n"
                 "  td => {file, \"lamp.json\"}, max_size => 2000000}]}.\n"),
    has("{wot_avatars, #{entity_id => \"lamp\"}}.\n", "wot_avatars: the value must be a list"),
    has("{wot_avatars, [lamp]}.\n", "wot_avatars entry 1: a WoT Avatar is a map").

%% An entity id twice among the WoT Avatars, or shared with an MQTT
%% Avatar, is a mistake of the file.
wot_avatar_entity_ids_are_unique_test() ->
    Wot = fun(Id) -> "#{entity_id => \"" ++ Id ++ "\", pairing => \"home\", td => \"http://h/t\"}" end,
    has(?PAIRING "{wot_avatars, [" ++ Wot("lamp") ++ ", " ++ Wot("lamp") ++ "]}.\n",
        "wot_avatars: entity_id \"lamp\" appears more than once"),
    has(?PAIRING ?AVATAR("") "{wot_avatars, [" ++ Wot("house") ++ "]}.\n",
        "wot_avatars: entity_id \"house\" also names an MQTT Avatar (mqtt_avatars)").

%% Per-device identities: text becomes binaries, roles stay the two
%% words, fingerprints and hashed credentials pass to evatar, which accepts
%% the pairing without role credentials.
identities_are_accepted_test() ->
    Fp = lists:join(":", lists:duplicate(32, "AB")),
    {ok, #{pairings := [P], mqtt_avatars := [A]}} =
        load("{pairings, [#{id => \"home\",\n"
             "              identities => [#{entity => \"kitchen-va\", role => agent, credential => \"va-own\"},\n"
             "                             #{entity => \"house\", role => avatar, credential => \"house-own\"},\n"
             "                             #{entity => \"hall-cam\", role => avatar, cert_sha256 => \"" ++ Fp ++ "\"}],\n"
             "              unlisted_ids => refuse}]}.\n" ?AVATAR("")),
    #{id := <<"home">>, unlisted_ids := refuse,
      identities := [#{entity := <<"kitchen-va">>, role := agent, credential := <<"va-own">>},
                     #{entity := <<"house">>, role := avatar, credential := <<"house-own">>},
                     #{entity := <<"hall-cam">>, role := avatar, cert_sha256 := FpBin}]} = P,
    ?assertEqual(list_to_binary(Fp), FpBin),
    false = maps:is_key(agent_credential, P),
    ok = evatar:check_pairing_opts(maps:remove(id, P)),
    %% The Avatar listed in the identities joins with its own credential.
    #{evatar := #{credential := <<"house-own">>}} = A,
    %% Listed devices and role credentials together.
    {ok, #{pairings := [#{unlisted_ids := role_credential}], mqtt_avatars := [#{evatar := E}]}} =
        load("{pairings, [#{id => \"home\", agent_credential => \"a\", avatar_credential => \"b\",\n"
             "              identities => [#{entity => \"va\", role => agent, credential => \"c\"}],\n"
             "              unlisted_ids => role_credential}]}.\n" ?AVATAR("")),
    #{credential := <<"b">>} = E.

%% bin/evatar hash_credential's output, pasted in the file, is kept as the
%% hash: the joining secret verifies, another does not.
hashed_credentials_test() ->
    Agent = node_config:hashed_credential(<<"va secret">>),
    Own = node_config:hashed_credential(<<"house secret">>),
    {ok, #{pairings := [P], mqtt_avatars := [#{evatar := E}]}} =
        load(["{pairings, [#{id => \"home\", agent_credential => ", Agent, ",\n"
              "              identities => [#{entity => \"house\", role => avatar, credential => ", Own,
              "}],\n              unlisted_ids => role_credential}]}.\n",
              ?AVATAR(", credential => \"house secret\"")]),
    #{agent_credential := {pbkdf2_sha256, _, _, _} = H,
      identities := [#{credential := {pbkdf2_sha256, _, _, _} = H2}]} = P,
    ok = evatar:check_pairing_opts(maps:remove(id, P)),
    authenticated = evatar_auth:verify(#{credential => H}, <<"va secret">>),
    bad_credential = evatar_auth:verify(#{credential => H}, <<"va secreT">>),
    authenticated = evatar_auth:verify(#{credential => H2}, <<"house secret">>),
    #{credential := <<"house secret">>} = E,
    %% Without its own plain credential, an Avatar cannot join with a hash.
    has(["{pairings, [#{id => \"home\", agent_credential => \"a\", avatar_credential => ", Agent,
         "}]}.\n", ?AVATAR("")],
        "mqtt_avatars entry 1 (house): credential => \"...\" required: pairing \"home\" has no plain "
        "avatar_credential"),
    has("{pairings, [#{id => \"home\", agent_credential => {pbkdf2_sha256, 0, <<>>, <<1,2>>}, "
        "avatar_credential => \"b\"}]}.",
        "pairings entry 1 (home): agent_credential is not a hashed credential").

wrong_identities_test() ->
    Pairing = fun(Ids) -> "{pairings, [#{id => \"home\", identities => [" ++ Ids ++ "]}]}.\n" end,
    has(Pairing("#{entity => \"va\", role => agent}"),
        "line 1: pairings entry 1 (home): identity \"va\": credential or cert_sha256 required"),
    has(Pairing("#{entity => \"va\", role => agent, cert_sha256 => \"abc\"}"),
        "identity \"va\": cert_sha256 \"abc\" is not a SHA-256 fingerprint"),
    has(Pairing("#{entity => \"va\", role => agent, credential => \"a\"}, "
                "#{entity => \"va\", role => avatar, credential => \"b\"}"),
        "identities: an entity appears more than once"),
    has(Pairing("#{entity => \"va\", role => true, credential => \"a\"}"),
        "an identity needs entity (text, not empty) and role (agent or avatar)"),
    has(Pairing("#{entity => \"va\", role => agent, credential => \"\"}"),
        "pairings entry 1 (home): identities entry 1 (va): credential must be a secret"),
    has(Pairing("#{entity => \"va\", role => agent, credential => 42}"),
        "identities entry 1 (va): credential must be a secret"),
    has(Pairing("\"va\""), "identities entry 1: an identity is a map"),
    has("{pairings, [#{id => \"home\", identities => #{}}]}.", "identities must be a list"),
    has("{pairings, [#{id => \"home\", agent_credential => \"a\", avatar_credential => \"b\", "
        "unlisted_ids => true}]}.", "unlisted_ids must be refuse or role_credential"),
    has("{pairings, [#{id => \"home\"}]}.",
        "agent_credential, avatar_credential required (no default credentials: choose a secret), "
        "unless the pairing lists identities"),
    %% A role that is not a word of the file is refused without becoming an atom.
    Word = "zz_role_" ++ integer_to_list(erlang:unique_integer([positive])),
    has(Pairing("#{entity => \"va\", role => " ++ Word ++ ", credential => \"a\"}"),
        "unknown word " ++ Word),
    ?assertError(badarg, list_to_existing_atom(Word)),
    %% An MQTT Avatar its pairing would refuse.
    has(Pairing("#{entity => \"va\", role => agent, credential => \"a\"}") ++ ?AVATAR(""),
        "mqtt_avatars entry 1 (house): pairing \"home\" would refuse it: \"house\" is not in its "
        "identities"),
    has(Pairing("#{entity => \"house\", role => agent, credential => \"a\"}") ++ ?AVATAR(""),
        "lists \"house\" in its identities with role agent"),
    has(Pairing("#{entity => \"house\", role => avatar, cert_sha256 => \"" ++ lists:duplicate(64, $a)
                ++ "\"}") ++ ?AVATAR(""),
        "credential => \"...\" required: the identity of \"house\" in pairing \"home\" has no plain "
        "credential"),
    %% An Avatar of a pairing with a mistake names the pairing, once.
    has(Pairing("#{entity => \"va\", role => agent}") ++ ?AVATAR(""),
        "mqtt_avatars entry 1 (house): pairing \"home\" has a mistake").

%% Removes the `%% ' of the example sections (from `%% {' to `]}.').
uncomment(Bin) ->
    Lines = string:split(binary_to_list(Bin), "\n", all),
    {Out, _} = lists:mapfoldl(
                 fun("%% {" ++ _ = L, _) -> {lists:nthtail(3, L), true};
                    ("%%" ++ Rest = L, true) ->
                         Line = lists:nthtail(min(3, length(L)), L),
                         {Line, not lists:suffix("]}.", string:trim(Rest))};
                    (L, In) -> {L, In}
                 end, false, Lines),
    lists:join("\n", Out).

%% ---------------------------------------------------------------------------
%% Refused files: the file, the line, the entry and the mistake
%% ---------------------------------------------------------------------------

message_names_file_line_entry_test() ->
    {error, {bad_config, File, _} = E} = load(?PAIRING "\n{mqtt_avatars, [#{entity_id => \"house\", "
                                              "pairing => \"flat\", mqtt => #{host => \"h\", port => 1}}]}."),
    Text = node_config:format_error(E),
    Expected = iolist_to_binary([File, ": line 3: mqtt_avatars entry 1 (house): pairing \"flat\" is not "
                                 "declared in the pairings section\n"]),
    ?assertEqual(Expected, Text).

unknown_words_are_not_made_atoms_test() ->
    Word = "zz_" ++ integer_to_list(erlang:unique_integer([positive])),
    has("{pairings, [#{id => \"home\", " ++ Word ++ " => 1}]}.", "unknown word " ++ Word),
    ?assertError(badarg, list_to_existing_atom(Word)),
    Quoted = "zz q " ++ integer_to_list(erlang:unique_integer([positive])),
    has("{pairings, ['" ++ Quoted ++ "']}.", "unknown word " ++ Quoted),
    ?assertError(badarg, list_to_existing_atom(Quoted)).

strings_comments_and_chars_are_not_atoms_test() ->
    {ok, _} = load("%% zz_never_an_atom here\n"
                   "{pairings, [#{id => \"zz not an atom\", agent_credential => \"it's\", "
                   "avatar_credential => [$z, $\\n, $']}]}.\n").

unknown_keys_test() ->
    has("{listeners, [#{port => 1, acceptor => 2}]}.", "listeners entry 1: unknown listener option acceptor"),
    has("{listeners, [#{conn => #{timeout => 2}}]}.", "unknown connection option timeout"),
    has(?PAIRING ?AVATAR(", timeout => 3"), "mqtt_avatars entry 1 (house): unknown key timeout"),
    has(?PAIRING "{mqtt_avatars, [#{entity_id => \"a\", pairing => \"home\", "
        "mqtt => #{host => \"h\", port => 1, user => \"x\"}}]}.", "mqtt: unknown key user"),
    has(?PAIRING ?AVATAR(", overrides => #{\"x\" => #{rooms => \"a\"}}"), "override \"x\": unknown key rooms"),
    has(?PAIRING ?AVATAR(", discovery => #{home => \"a\"}"), "discovery: unknown key home"),
    %% zigbee2mqtt's device list limit, bounded (docs/mqtt.md section 6).
    has(?PAIRING ?AVATAR(", discovery => #{max_device_list_size => 67108865}"),
        "max_device_list_size must be an integer from 1 to 67108864 (bytes)").

wrong_types_test() ->
    has("{listeners, [#{port => \"7400\"}]}.", "port must be an integer"),
    has("{listeners, [#{ip => \"localhost\"}]}.", "ip \"localhost\" is not an IP address"),
    has("{pairings, [#{id => home, agent_credential => \"a\", avatar_credential => \"b\"}]}.",
        "id must be text"),
    has("{pairings, [#{id => \"h\", agent_credential => \"a\", avatar_credential => \"b\", "
        "join_timeout => -1}]}.", "join_timeout -1 is not accepted: an integer from 0 to 4294967295"),
    has("{pairings, [#{id => \"h\", agent_credential => \"a\", avatar_credential => \"b\", "
        "feedback_timeout => 1000000000000000000000000000000}]}.",
        "feedback_timeout 1000000000000000000000000000000 is not accepted: an integer from 0 to "
        "4294967295 (milliseconds)"),
    has("{pairings, [#{id => \"h\", agent_credential => \"a\", avatar_credential => \"b\", "
        "max_avatars => 65537}]}.", "max_avatars 65537 is not accepted: an integer from 1 to 65536"),
    has(?PAIRING ?AVATAR(", settle => \"soon\""), "settle must be an integer"),
    has(?PAIRING "{mqtt_avatars, [#{entity_id => \"a\", pairing => \"home\", "
        "mqtt => #{host => \"h\", port => 0}}]}.", "port must be an integer of at least 1"),
    has(?PAIRING ?AVATAR(", discovery => true"), "discovery must be a map"),
    has(?PAIRING ?AVATAR(", restart => #{min_ms => 0}"), "min_ms must be an integer of at least 1"),
    has("{pairings, #{id => \"h\"}}.", "pairings: the value must be a list"),
    has("{pairings, [42]}.", "pairings entry 1: a pairing is a map").

missing_and_undeclared_test() ->
    has("{pairings, [#{id => \"h\", agent_credential => \"a\"}]}.",
        "avatar_credential required (no default credentials"),
    has("{pairings, [#{id => \"h\", agent_credential => \"\", avatar_credential => \"b\"}]}.",
        "agent_credential must be a secret in double quotes, not empty"),
    has("{pairings, [#{agent_credential => \"a\", avatar_credential => \"b\"}]}.", "id (text"),
    has(?AVATAR(""), "pairing \"home\" is not declared"),
    has(?PAIRING "{mqtt_avatars, [#{entity_id => \"a\", pairing => \"home\"}]}.", "mqtt required"),
    has(?PAIRING "{listeners, [#{port => 0}]}.\n" ?AVATAR(""),
        "endpoints are required: this node's first listener has port 0").

duplicates_test() ->
    has("{pairings, [#{id => \"h\", agent_credential => \"a\", avatar_credential => \"b\"},"
        " #{id => \"h\", agent_credential => \"c\", avatar_credential => \"d\"}]}.",
        "pairings: id \"h\" appears more than once"),
    has(?PAIRING "{mqtt_avatars, [#{entity_id => \"a\", pairing => \"home\", mqtt => #{host => \"h\", port => 1}},"
        " #{entity_id => \"a\", pairing => \"home\", mqtt => #{host => \"h\", port => 2}}]}.",
        "mqtt_avatars: entity_id \"a\" appears more than once"),
    has("{listeners, [#{port => 7400}, #{ip => \"127.0.0.1\", port => 7400}]}.",
        "address 127.0.0.1 port 7400 appears more than once"),
    has("{listeners, [#{name => \"a\", port => 0}, #{name => \"a\", port => 0}]}.",
        "name <<\"a\">> appears more than once"),
    has(?PAIRING ?PAIRING, "line 2: pairings: the section appears a second time").

syntax_and_shape_test() ->
    has("{pairings, [#{id => \"h\"}]}", "line 1: the file ends inside the entry"),
    has("{pairings, [#{id => \"h\",, port => 1}]}.", "line 1: syntax error before"),
    has("{pairings, [#{id => \"h}]}.", "line 1:"),
    has("{pairings, [X]}.", "only plain values here"),
    has("{pairings, [lists:seq(1, 2)]}.", "only plain values here"),
    has("pairings.", "each entry of the file is {section, [...]}."),
    has("{gizmos, []}.", "unknown word gizmos"),
    has("{timeout, []}.", "timeout: unknown section"),
    has(?PAIRING ?AVATAR(", description => \"no-such.xml\""), "no-such.xml").

missing_file_test() ->
    {error, {bad_config, "/nonexistent/evatar.config", [<<"cannot be read: no such file or directory">>]}} =
        node_config:load("/nonexistent/evatar.config").

%% Every independent mistake of an entry at once, one line each with the
%% entry's line and label (MQTT_REVIEW D9: `discover' and a port in
%% quotes came one run apart). What needs the keys right (the pairing an
%% Avatar joins, mqtt_avatar's own check of its options) waits for them.
every_mistake_of_an_entry_test() ->
    Ps = problems(?PAIRING "{mqtt_avatars, [#{entity_id => \"house\", pairing => \"home\",\n"
                  "  discover => #{}, settle => \"soon\",\n"
                  "  mqtt => #{host => \"h\", port => \"18830\", user => \"me\"},\n"
                  "  overrides => #{\"a\" => #{rooms => 1}, \"b\" => #{skip => maybe}}}]}.\n"),
    ?assertEqual([<<"line 2: mqtt_avatars entry 1 (house): unknown key discover (known: entity_id, "
                    "pairing, endpoints, credential, mqtt, discovery, description, overrides, "
                    "api_name, settle, discovery_wait, echo_timeout, retry, timestamp_field, "
                    "restart, birth)">>,
                  <<"line 2: mqtt_avatars entry 1 (house): settle must be an integer of at least 0">>,
                  <<"line 2: mqtt_avatars entry 1 (house): mqtt: unknown key user (known: client_id, "
                    "username, password, host, port, protocol, clean_start, session_expiry, "
                    "keepalive, tls, reconnect, inflight_window, retry_interval, connect_timeout, "
                    "max_packet_size)">>,
                  <<"line 2: mqtt_avatars entry 1 (house): mqtt: port must be an integer of at least 1">>,
                  <<"line 2: mqtt_avatars entry 1 (house): overrides: override \"a\": unknown key rooms "
                    "(known: component, room, skip, parameters, services, consumes, feedback)">>,
                  <<"line 2: mqtt_avatars entry 1 (house): overrides: override \"b\": skip must be one "
                    "of true, false">>],
                 Ps),
    %% A pairing: its id and both credentials.
    [<<"line 1: pairings entry 1: id (text", _/binary>>,
     <<"line 1: pairings entry 1: agent_credential, avatar_credential must be a secret", _/binary>>] =
        problems("{pairings, [#{agent_credential => \"\", avatar_credential => 7}]}.\n"),
    %% Once the keys read: an undeclared pairing and an unreadable
    %% description, together; not while a key is wrong.
    [<<"line 2: mqtt_avatars entry 1 (house): ", D/binary>>,
     <<"line 2: mqtt_avatars entry 1 (house): pairing \"flat\" is not declared", _/binary>>] =
        problems(?PAIRING "{mqtt_avatars, [#{entity_id => \"house\", pairing => \"flat\", "
                 "mqtt => #{host => \"h\", port => 1}, description => \"no-such.xml\"}]}.\n"),
    ?assertNotEqual(nomatch, binary:match(D, <<"no-such.xml">>)),
    [<<"line 2: mqtt_avatars entry 1 (house): retry must be", _/binary>>] =
        problems(?PAIRING "{mqtt_avatars, [#{entity_id => \"house\", pairing => \"flat\", "
                 "mqtt => #{host => \"h\", port => 1}, retry => 0}]}.\n").

%% However many mistakes an entry has, it takes at most ten lines.
mistakes_are_bounded_test() ->
    Overrides = lists:join(", ", [io_lib:format("\"o~b\" => #{skip => ~b}", [N, N])
                                  || N <- lists:seq(1, 30)]),
    Ps = problems(?PAIRING ?AVATAR(", overrides => #{" ++ lists:flatten(Overrides) ++ "}")),
    ?assertEqual(10, length(Ps)),
    ?assertNotEqual(nomatch, binary:match(lists:last(Ps), <<"and 21 more mistakes">>)).

%% An unknown word is a mistake, and the reading goes on: the other
%% mistakes of its entry (and of the file) are named in the same run. A
%% misspelt key is left out, a misspelt value reads as the text it spells.
unknown_word_does_not_stop_the_reading_test() ->
    W1 = "zz_" ++ integer_to_list(erlang:unique_integer([positive])),
    W2 = "zz_" ++ integer_to_list(erlang:unique_integer([positive])),
    Ps = problems("{pairings, [#{id => \"home\", agent_credential => \"a\", avatar_credential => \"b\",\n"
                  "  " ++ W1 ++ " => 1, join_timeout => -1, max_avatars => \"many\",\n"
                  "  unlisted_ids => " ++ W2 ++ "}]}.\n"
                  "{mqtt_avatars, [#{entity_id => \"house\", pairing => \"home\",\n"
                  "  mqtt => #{host => \"h\", port => \"1\", protocol => '" ++ W2 ++ "'}}]}.\n"),
    %% In the order of their lines (an entry's at the line it starts).
    ?assertMatch([<<"line 1: pairings entry 1 (home): ", _/binary>>,
                  <<"line 1: pairings entry 1 (home): ", _/binary>>,
                  <<"line 1: pairings entry 1 (home): ", _/binary>>,
                  <<"line 2: unknown word ", _/binary>>,
                  <<"line 3: unknown word ", _/binary>>,
                  <<"line 4: mqtt_avatars entry 1 (house): mqtt: port must be an integer", _/binary>>,
                  <<"line 4: mqtt_avatars entry 1 (house): mqtt: protocol must be one of v311, v5">>,
                  <<"line 5: unknown word ", _/binary>>],
                 Ps, Ps),
    Text = iolist_to_binary(lists:join("\n", Ps)),
    [?assertNotEqual(nomatch, binary:match(Text, list_to_binary(S)), {S, Ps})
     || S <- ["line 2: unknown word " ++ W1, "line 3: unknown word " ++ W2,
              "line 5: unknown word " ++ W2, "join_timeout -1", "max_avatars \"many\"",
              "unlisted_ids must be refuse or role_credential"]],
    ?assertEqual(8, length(Ps)),
    ?assertError(badarg, list_to_existing_atom(W1)),
    ?assertError(badarg, list_to_existing_atom(W2)),
    %% Only the first twenty unknown words are named.
    Many = lists:flatten([io_lib:format("zz_many_~b => 1, ", [N]) || N <- lists:seq(1, 25)]),
    Ps2 = problems("{pairings, [#{" ++ Many ++ "id => \"x\", agent_credential => \"a\", "
                   "avatar_credential => \"b\"}]}.\n"),
    ?assertEqual(21, length(Ps2)),
    ?assertEqual(<<"line 1: and 5 more unknown words">>, lists:last(Ps2)).

%% Every mistake of the http section in one run: an unknown key, an ip
%% that is no address, and evatar_web's verdict on each key that read (a
%% port out of range, a max_clients that is no positive integer).
every_mistake_of_the_http_section_test() ->
    Ps = problems("{http, #{colour => \"red\", ip => \"no-address\", port => 70000,\n"
                  "         max_clients => 0, enabled => true}}.\n"),
    ?assertMatch([<<"line 1: http: unknown key colour", _/binary>>,
                  <<"line 1: http: ip \"no-address\" is not an IP address">>,
                  <<"line 1: http: max_clients: ", _/binary>>,
                  <<"line 1: http: port: ", _/binary>>], Ps).
