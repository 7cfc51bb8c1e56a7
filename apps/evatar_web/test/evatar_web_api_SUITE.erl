%% Common Test: every /api route of evatar_web over real TCP, with good and
%% bad input and the operator credential, on a pairing joined by a real VA
%% and a real Avatar (agent_bridge_client over the bridge's TCP listener).
%% The last case checks every answer the live server gave against
%% priv/openapi.json with a real validator (Python's openapi-core).
-module(evatar_web_api_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-import(evatar_test_wait, [until/1]).

-export([all/0, groups/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([reads_open_on_loopback/1, changes_need_the_token/1, no_token_refuses_changes/1,
         off_loopback_reads_need_the_token/1, token_file/1,
         cluster/1, pairings_list/1, pairing_entities/1, bindings_graph/1,
         create_refusals/1, create_then_delete/1, change_options/1, rotate_role_credential/1,
         rotate_identity_generated/1, mqtt_avatar_routes/1, wot_avatar_routes/1, openapi_document/1,
         live_answers_match_openapi/1]).

-define(T, evatar_web_test).
-define(TOKEN, <<"operator-token-for-tests-0123456789">>).
-define(PAIRING, <<"web-home">>).
-define(VA_CRED, <<"va-secret-123">>).
-define(AV_CRED, <<"av-secret-456">>).
-define(MQTT_AV, <<"web-plug">>).
-define(MQTT_PAIRING, <<"web-mqtt">>).
%% A kept WoT Avatar (a TD file: no Thing needs to answer) and its pairing.
-define(WOT_AV, <<"web-lamp">>).
-define(WOT_PAIRING, <<"web-wot">>).

suite() -> [{timetrap, {minutes, 3}}].

all() -> [{group, auth}, {group, routes}].

groups() ->
    [{auth, [], [reads_open_on_loopback, changes_need_the_token, no_token_refuses_changes,
                 off_loopback_reads_need_the_token, token_file]},
     {routes, [], [cluster, pairings_list, pairing_entities, bindings_graph, create_refusals,
                   create_then_delete, change_options, rotate_role_credential,
                   rotate_identity_generated, mqtt_avatar_routes, wot_avatar_routes, openapi_document,
                   live_answers_match_openapi]}].

init_per_suite(Config) ->
    ok = application:set_env(agent_bridge, listeners, [], [{persistent, true}]),
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = application:ensure_all_started(mqtt_avatar),
    {ok, _} = application:ensure_all_started(wot_avatar),
    {ok, _} = agent_bridge:start_listener(web_api_test, #{port => 0}),
    {ok, Addr} = agent_bridge:address(web_api_test),
    ?T:start(#{operator_token_hash => evatar:hash_credential(?TOKEN)}),
    _ = evatar:delete_pairing(?PAIRING),
    {201, #{<<"id">> := ?PAIRING}} =
        change(post, "/api/pairings", #{id => ?PAIRING, agent_credential => ?VA_CRED,
                                        avatar_credential => ?AV_CRED, join_timeout => 60000}),
    %% The clients belong to a process that outlives init_per_suite's.
    Self = self(),
    Holder = spawn(fun() ->
                           {ok, Va} = agent_bridge_client:connect(
                                        [Addr], #{pairing => ?PAIRING, role => agent,
                                                  entity_id => <<"va">>, credential => ?VA_CRED}),
                           {ok, Av} = agent_bridge_client:connect(
                                        [Addr], #{pairing => ?PAIRING, role => avatar,
                                                  entity_id => <<"av">>, credential => ?AV_CRED}),
                           ok = agent_bridge_client:describe(Av, avatar_description()),
                           ok = agent_bridge_client:describe(Va, va_description()),
                           Self ! joined,
                           receive stop -> [agent_bridge_client:close(C) || C <- [Va, Av]] end
                   end),
    receive joined -> ok after evatar_test_time:guard() -> ct:fail(clients_did_not_join) end,
    %% A real MQTT Avatar (mosquitto, a hand-written description) kept by
    %% this node, joined to the pairing over TCP.
    %% Its own pairing: the counts of ?PAIRING do not depend on when it joins.
    Broker = start_mosquitto(?config(priv_dir, Config)),
    _ = evatar:delete_pairing(?MQTT_PAIRING),
    {ok, _} = evatar:create_pairing(?MQTT_PAIRING, #{agent_credential => ?VA_CRED,
                                                     avatar_credential => ?AV_CRED}),
    {ok, _} = mqtt_avatar:keep(#{entity_id => ?MQTT_AV, mqtt => #{host => "127.0.0.1", port => element(2, Broker)},
                                 evatar => #{endpoints => [Addr], pairing => ?MQTT_PAIRING,
                                             credential => ?AV_CRED},
                                 description => mqtt_xml(<<"Plug01">>), discovery => false}),
    %% A kept WoT Avatar, its TD read from a file, joined to its own pairing.
    _ = evatar:delete_pairing(?WOT_PAIRING),
    {ok, _} = evatar:create_pairing(?WOT_PAIRING, #{agent_credential => ?VA_CRED,
                                                    avatar_credential => ?AV_CRED}),
    Td = filename:join(?config(priv_dir, Config), "web-lamp.td.json"),
    ok = file:write_file(Td, evatar_test_fixtures:wot_lamp_td(<<"web-lamp">>)),
    {ok, _} = wot_avatar:keep(#{entity_id => ?WOT_AV, td => {file, Td}, allowed_hosts => [<<"127.0.0.1">>],
                                evatar => #{endpoints => [Addr], pairing => ?WOT_PAIRING,
                                            credential => ?AV_CRED}}),
    until(fun() ->
                  case ?T:get("/api/pairings/" ++ binary_to_list(?PAIRING) ++ "/bindings") of
                      {200, #{<<"bound">> := [_ | _], <<"unbound">> := [_, _]}} -> true;
                      _ -> false
                  end
          end),
    [{addr, Addr}, {holder, Holder}, {broker, Broker} | Config].

end_per_suite(Config) ->
    ?config(holder, Config) ! stop,
    _ = mqtt_avatar:unkeep(?MQTT_AV),
    _ = evatar:delete_pairing(?MQTT_PAIRING),
    _ = wot_avatar:unkeep(?WOT_AV),
    _ = evatar:delete_pairing(?WOT_PAIRING),
    %% mosquitto does not end when its port closes: killed by its pid.
    _ = os:cmd("kill " ++ integer_to_list(element(3, ?config(broker, Config)))),
    _ = evatar:delete_pairing(?PAIRING),
    ok = agent_bridge:stop_listener(web_api_test),
    ?T:stop().

%% ---------------------------------------------------------------------------
%% The operator credential
%% ---------------------------------------------------------------------------

%% A loopback listener answers reads without a token, and with the right one.
reads_open_on_loopback(_Config) ->
    {200, _} = ?T:get("/api/pairings"),
    {200, _} = ?T:get("/api/pairings", [auth(?TOKEN)]),
    %% A wrong token sent with a read is checked, not ignored.
    {401, #{<<"error">> := <<"bad_token">>}} = ?T:get("/api/pairings", [auth(<<"wrong">>)]).

%% Every change needs the token: none, a wrong one, a malformed header.
changes_need_the_token(_Config) ->
    Body = json(#{id => <<"nope">>, agent_credential => ?VA_CRED, avatar_credential => ?AV_CRED}),
    {401, #{<<"error">> := <<"unauthorized">>}} = ?T:request(post, "/api/pairings", [], Body),
    {401, #{<<"error">> := <<"bad_token">>}} =
        ?T:request(post, "/api/pairings", [auth(<<"not-the-token">>)], Body),
    {401, #{<<"error">> := <<"unauthorized">>}} =
        ?T:request(post, "/api/pairings", [{"authorization", "Basic dXNlcjpwYXNz"}], Body),
    {401, #{<<"error">> := <<"unauthorized">>}} =
        ?T:request(delete, "/api/pairings/" ++ binary_to_list(?PAIRING), [], none),
    {_, Headers, _} = ?T:raw(delete, "/api/pairings/" ++ binary_to_list(?PAIRING), [], none),
    "Bearer realm=\"evatar\"" = proplists:get_value("www-authenticate", Headers),
    {404, _} = ?T:get("/api/pairings/nope"),
    {200, _} = ?T:get("/api/pairings/" ++ binary_to_list(?PAIRING)).

%% Without a configured token every change is refused, saying how to set one.
no_token_refuses_changes(_Config) ->
    try
        ?T:restart(#{}),
        {403, #{<<"error">> := <<"no_operator_token">>, <<"message">> := M}} =
            change(post, "/api/pairings", #{id => <<"x">>}),
        {match, _} = re:run(M, "operator_token_hash"),
        {403, _} = ?T:request(delete, "/api/pairings/" ++ binary_to_list(?PAIRING),
                              [auth(?TOKEN)], none),
        {200, _} = ?T:get("/api/cluster")
    after
        ?T:restart(#{operator_token_hash => evatar:hash_credential(?TOKEN)})
    end.

%% On a listener off loopback (0.0.0.0) reads need the token too.
off_loopback_reads_need_the_token(_Config) ->
    try
        ?T:restart(#{ip => {0, 0, 0, 0}, operator_token_hash => evatar:hash_credential(?TOKEN)}),
        {401, #{<<"error">> := <<"unauthorized">>}} = ?T:get("/api/cluster"),
        {401, _} = ?T:get("/api/pairings"),
        {200, _} = ?T:get("/api/cluster", [auth(?TOKEN)]),
        %% The page's files hold no data: served without a token.
        {200, _, _} = ?T:raw(get, "/", [], none),
        ?T:restart(#{ip => {0, 0, 0, 0}}),
        {403, #{<<"error">> := <<"no_operator_token">>}} = ?T:get("/api/cluster")
    after
        ?T:restart(#{operator_token_hash => evatar:hash_credential(?TOKEN)})
    end.

%% EVATAR_HTTP_TOKEN_FILE: the file's first line is the token.
token_file(Config) ->
    File = filename:join(?config(priv_dir, Config), "token"),
    ok = file:write_file(File, <<"file-token-abcdefgh\nignored\n">>),
    try
        ?T:restart(#{token_file => File}),
        {404, _} = ?T:request(delete, "/api/pairings/none-such", [auth(<<"file-token-abcdefgh">>)], none),
        {401, _} = ?T:request(delete, "/api/pairings/none-such", [auth(?TOKEN)], none)
    after
        ?T:restart(#{operator_token_hash => evatar:hash_credential(?TOKEN)})
    end.

%% ---------------------------------------------------------------------------
%% Routes
%% ---------------------------------------------------------------------------

%% The cluster: this node, up, quorum, the pairing active here.
cluster(_Config) ->
    {200, #{<<"quorum">> := true, <<"pairings">> := Ps}} = ?T:get("/api/cluster"),
    [#{<<"active">> := Node, <<"standby">> := null, <<"epoch">> := E, <<"synced">> := _}] =
        [P || #{<<"id">> := Id} = P <- Ps, Id =:= ?PAIRING],
    Node = atom_to_binary(node()),
    true = E >= 1.

%% The list has the pairing with its agent, avatars and counts.
pairings_list(_Config) ->
    {200, Ps} = ?T:get("/api/pairings"),
    [#{<<"agent">> := <<"va">>, <<"avatars">> := 1, <<"registered">> := 2, <<"bound">> := B,
       <<"unbound">> := 2, <<"role">> := <<"active">>}] =
        [P || #{<<"id">> := Id} = P <- Ps, Id =:= ?PAIRING],
    true = B >= 1.

%% A pairing's entities with their state and components; options without
%% any credential.
pairing_entities(_Config) ->
    {200, #{<<"entities">> := Es, <<"options">> := Opts, <<"ha">> := #{<<"role">> := <<"active">>},
            <<"stats">> := #{}}} = ?T:get("/api/pairings/" ++ binary_to_list(?PAIRING)),
    #{<<"va">> := #{<<"role">> := <<"agent">>, <<"state">> := <<"described">>,
                    <<"connected">> := true, <<"described">> := true, <<"detached">> := false},
      <<"av">> := #{<<"role">> := <<"avatar">>, <<"components">> := [_, _]}} =
        maps:from_list([{E, X} || #{<<"entity">> := E} = X <- Es]),
    #{<<"agent_credential">> := <<"set">>, <<"join_timeout">> := 60000} = Opts,
    nomatch = binary:match(evatar_json:encode(Opts), [?VA_CRED, ?AV_CRED]),
    {404, #{<<"error">> := <<"not_found">>, <<"field">> := <<"id">>}} = ?T:get("/api/pairings/nope"),
    %% A percent-encoded id is decoded, never made an atom.
    {404, _} = ?T:get("/api/pairings/a%2Fb%20c").

%% The Body Mapping Registry as a graph: both sides' components, the bound
%% edge with its service, the unbound entries with their reasons and the
%% parameter that did not match.
bindings_graph(_Config) ->
    {200, G} = ?T:get("/api/pairings/" ++ binary_to_list(?PAIRING) ++ "/bindings"),
    #{<<"agents">> := [#{<<"entity">> := <<"va">>, <<"components">> := [_]}],
      <<"avatars">> := [#{<<"entity">> := <<"av">>, <<"components">> := [_, _]}],
      <<"bound">> := Bound, <<"unbound">> := Unbound} = G,
    [#{<<"consumer">> := #{<<"entity">> := <<"va">>, <<"component">> := <<"LightEmulator01">>},
       <<"provider">> := #{<<"entity">> := <<"av">>, <<"component">> := <<"Light01">>},
       <<"category">> := <<"ACTUATOR">>, <<"type">> := <<"TurnLightOn">>}] = Bound,
    Reasons = maps:from_list([{T, U} || #{<<"type">> := T} = U <- Unbound]),
    #{<<"OpenDoor">> := #{<<"reason">> := <<"NoProvider">>, <<"candidates">> := [],
                          <<"more_candidates">> := 0},
      <<"Dim">> := #{<<"reason">> := <<"ParametersMismatch">>, <<"more_candidates">> := 0,
                     <<"candidates">> := [#{<<"provider">> := #{<<"component">> := <<"Dimmer01">>},
                                            <<"mismatches">> := [#{<<"name">> := <<"Room">>,
                                                                   <<"wanted">> := <<"kitchen">>}]}]}} =
        Reasons,
    {404, _} = ?T:get("/api/pairings/nope/bindings").

%% Bad input to create: each gets a 4xx naming the field; nothing is created.
create_refusals(_Config) ->
    Good = #{id => <<"web-new">>, agent_credential => ?VA_CRED, avatar_credential => ?AV_CRED},
    [{Status, #{<<"error">> := Code, <<"field">> := Field}} = change(post, "/api/pairings", Body)
     || {Status, Code, Field, Body} <-
            [{400, <<"bad_request">>, <<"id">>, maps:remove(id, Good)},
             {400, <<"bad_request">>, <<"id">>, Good#{id => binary:copy(<<"x">>, 129)}},
             {400, <<"bad_request">>, <<"id">>, Good#{id => 12}},
             {400, <<"bad_request">>, <<"colour">>, Good#{colour => <<"red">>}},
             {400, <<"bad_request">>, <<"join_timeout">>, Good#{join_timeout => -1}},
             {400, <<"bad_request">>, <<"join_timeout">>, Good#{join_timeout => <<"5">>}},
             {400, <<"bad_request">>, <<"max_avatars">>, Good#{max_avatars => 0}},
             %% Past a range: a timer past erlang:start_timer/3's limit crashed the pairing.
             {400, <<"bad_request">>, <<"join_timeout">>, Good#{join_timeout => 1000000000000000000000000000000}},
             {400, <<"bad_request">>, <<"feedback_timeout">>, Good#{feedback_timeout => 4294967296}},
             {400, <<"bad_request">>, <<"resume_timeout">>, Good#{resume_timeout => 4294967296}},
             {400, <<"bad_request">>, <<"max_avatars">>, Good#{max_avatars => 1000000000000000000000}},
             {400, <<"bad_request">>, <<"dedup_window">>, Good#{dedup_window => 1048577}},
             {400, <<"bad_request">>, <<"max_binding_report">>, Good#{max_binding_report => 100}},
             {400, <<"bad_request">>, <<"agent_credential">>, Good#{agent_credential => <<"short">>}},
             {400, <<"bad_request">>, <<"avatar_credential">>, maps:remove(avatar_credential, Good)},
             {400, <<"bad_request">>, <<"unlisted_ids">>, Good#{unlisted_ids => <<"maybe">>}},
             {404, <<"not_found">>, <<"standby_node">>, Good#{standby_node => <<"nobody@nowhere">>}},
             {400, <<"bad_request">>, <<"standby_node">>, Good#{standby_node => 7}},
             %% Lengths count characters, as the document's maxLength does.
             {400, <<"bad_request">>, <<"id">>, Good#{id => binary:copy(<<"é"/utf8>>, 129)}},
             {400, <<"bad_request">>, <<"agent_credential">>,
              Good#{agent_credential => binary:copy(<<"é"/utf8>>, 7)}},
             {400, <<"bad_request">>, <<"identities">>,
              Good#{identities => [#{entity => <<"e">>, role => <<"robot">>, credential => ?VA_CRED}]}},
             {400, <<"bad_request">>, <<"identities">>,
              Good#{identities => [#{entity => <<"e">>, role => <<"agent">>}]}},
             {400, <<"bad_request">>, <<"identities">>,
              Good#{identities => [#{entity => <<"e">>, role => <<"agent">>, cert_sha256 => <<"zz">>}]}},
             {409, <<"already_exists">>, <<"id">>, Good#{id => ?PAIRING}}]],
    {400, #{<<"message">> := <<"must be an integer from 0 to 4294967295 (milliseconds)">>}} =
        change(post, "/api/pairings", Good#{join_timeout => 1000000000000000000000000000000}),
    {400, #{<<"error">> := <<"bad_json">>}} =
        ?T:request(post, "/api/pairings", [auth(?TOKEN)], "{\"id\": "),
    {400, #{<<"error">> := <<"bad_request">>}} =
        ?T:request(post, "/api/pairings", [auth(?TOKEN)], "[1,2]"),
    {404, _} = ?T:get("/api/pairings/web-new"),
    false = lists:member(<<"web-new">>, [Id || #{id := Id} <- evatar:pairings()]).

%% Create, read, delete; a second delete is a 404; lengths in characters.
create_then_delete(_Config) ->
    {201, #{<<"id">> := <<"web-tmp">>, <<"state">> := _}} =
        change(post, "/api/pairings", #{id => <<"web-tmp">>,
                                        identities => [#{entity => <<"cam">>, role => <<"avatar">>,
                                                         credential => <<"cam-secret-1">>}],
                                        agent_credential => ?VA_CRED}),
    {200, #{<<"options">> := #{<<"identities">> := [#{<<"entity">> := <<"cam">>,
                                                       <<"credential">> := true}]}}} =
        ?T:get("/api/pairings/web-tmp"),
    {200, #{<<"deleted">> := true}} = change(delete, "/api/pairings/web-tmp", none),
    {404, _} = ?T:get("/api/pairings/web-tmp"),
    {404, _} = change(delete, "/api/pairings/web-tmp", none),
    %% Lengths count characters, as the document's maxLength does: an id of
    %% 128 of them in 256 bytes, a credential of 1024 in 2048.
    Long = binary:copy(<<"é"/utf8>>, 128),
    {201, #{<<"id">> := Long}} =
        change(post, "/api/pairings", #{id => Long, avatar_credential => ?AV_CRED,
                                        agent_credential => binary:copy(<<"ü"/utf8>>, 1024)}),
    ok = evatar:delete_pairing(Long).

%% PUT replaces the options given and keeps the others; bad input changes nothing.
change_options(Config) ->
    {ok, _} = evatar:create_pairing(<<"web-chg">>, #{agent_credential => ?VA_CRED,
                                                     avatar_credential => ?AV_CRED}),
    {200, #{<<"options">> := #{<<"feedback_timeout">> := 1234, <<"join_timeout">> := 5000}}} =
        change(put, "/api/pairings/web-chg", #{feedback_timeout => 1234}),
    {400, #{<<"field">> := <<"feedback_timeout">>}} =
        change(put, "/api/pairings/web-chg", #{feedback_timeout => -5}),
    %% The body has options only: an id, another or the pairing's own, is refused.
    {400, #{<<"error">> := <<"bad_request">>, <<"field">> := <<"id">>}} =
        change(put, "/api/pairings/web-chg", #{id => <<"other">>, feedback_timeout => 99}),
    {400, #{<<"field">> := <<"id">>}} =
        change(put, "/api/pairings/web-chg", #{id => <<"web-chg">>, feedback_timeout => 99}),
    {404, _} = ?T:get("/api/pairings/other"),
    {400, #{<<"field">> := <<"join_timeout">>}} =
        change(put, "/api/pairings/web-chg", #{join_timeout => 4294967296}),
    {200, #{<<"options">> := #{<<"feedback_timeout">> := 1234}}} = ?T:get("/api/pairings/web-chg"),
    %% The old credentials still join.
    {ok, C} = agent_bridge_client:connect([?config(addr, Config)],
                                          #{pairing => <<"web-chg">>, role => agent,
                                            entity_id => <<"va">>, credential => ?VA_CRED}),
    ok = agent_bridge_client:close(C),
    {404, _} = change(put, "/api/pairings/nope", #{feedback_timeout => 1}),
    ok = evatar:delete_pairing(<<"web-chg">>).

%% Rotating the avatar credential: the new one joins, the old one is refused.
rotate_role_credential(Config) ->
    {ok, _} = evatar:create_pairing(<<"web-rot">>, #{agent_credential => ?VA_CRED,
                                                     avatar_credential => ?AV_CRED}),
    {200, R} = change(post, "/api/pairings/web-rot/rotate", #{role => <<"avatar">>,
                                                             credential => <<"new-avatar-secret">>}),
    false = maps:is_key(<<"credential">>, R),
    Join = fun(Cred) -> agent_bridge_client:connect([?config(addr, Config)],
                                                    #{pairing => <<"web-rot">>, role => avatar,
                                                      entity_id => <<"a1">>, credential => Cred})
           end,
    {error, _} = Join(?AV_CRED),
    {ok, C} = Join(<<"new-avatar-secret">>),
    ok = agent_bridge_client:close(C),
    {400, #{<<"field">> := <<"role">>}} = change(post, "/api/pairings/web-rot/rotate", #{role => <<"x">>}),
    {400, #{<<"field">> := <<"credential">>}} =
        change(post, "/api/pairings/web-rot/rotate", #{role => <<"agent">>, credential => <<"s">>}),
    {404, _} = change(post, "/api/pairings/nope/rotate", #{role => <<"agent">>}),
    ok = evatar:delete_pairing(<<"web-rot">>).

%% Rotating an identity without a credential given: a new random one, shown once.
rotate_identity_generated(Config) ->
    {ok, _} = evatar:create_pairing(<<"web-rid">>, #{agent_credential => ?VA_CRED,
                                                     identities => [#{entity => <<"cam">>, role => avatar,
                                                                      credential => <<"cam-secret-1">>}]}),
    {200, #{<<"credential">> := New}} =
        change(post, "/api/pairings/web-rid/rotate", #{entity => <<"cam">>}),
    true = byte_size(New) >= 16,
    {ok, C} = agent_bridge_client:connect([?config(addr, Config)],
                                          #{pairing => <<"web-rid">>, role => avatar,
                                            entity_id => <<"cam">>, credential => New}),
    ok = agent_bridge_client:close(C),
    {200, #{<<"options">> := Opts}} = ?T:get("/api/pairings/web-rid"),
    nomatch = binary:match(evatar_json:encode(Opts), New),
    {404, #{<<"field">> := <<"entity">>}} =
        change(post, "/api/pairings/web-rid/rotate", #{entity => <<"nobody">>}),
    ok = evatar:delete_pairing(<<"web-rid">>).

%% MQTT Avatars: the list, one shown with its description and problems,
%% its description overridden (it restarts with the new one; a broken one
%% is refused naming the problem), and an unknown one's routes.
mqtt_avatar_routes(Config) ->
    Path = "/api/mqtt_avatars/" ++ binary_to_list(?MQTT_AV),
    until(fun() -> element(1, ?T:get(Path)) =:= 200 end),
    {200, L} = ?T:get("/api/mqtt_avatars"),
    [#{<<"state">> := <<"running">>, <<"running">> := true}] =
        [A || #{<<"entity_id">> := E} = A <- L, E =:= ?MQTT_AV],
    {200, #{<<"components">> := [#{<<"id">> := <<"Plug01">>}], <<"description_xml">> := Xml,
            <<"problems">> := Ps}} = ?T:get(Path),
    {match, _} = re:run(Xml, "Plug01"),
    {200, Ps} = ?T:get(Path ++ "/problems"),
    %% A device's reading that is not a number, on its numeric stream
    %% (MqttNumeric): not passed on, and listed here.
    {ok, Device} = mqtt_client:start(#{host => {127, 0, 0, 1}, port => element(2, ?config(broker, Config))}),
    ok = mqtt_client:await_connected(Device, evatar_test_time:guard()),
    ok = mqtt_client:publish(Device, <<"tele/webplug/POWER_W">>, <<"abc">>, #{qos => 1, retain => true}),
    ok = mqtt_client:stop(Device),
    until(fun() ->
                  {200, Now} = ?T:get(Path ++ "/problems"),
                  [x || #{<<"what">> := <<"bad_payload">>, <<"topic">> := <<"tele/webplug/POWER_W">>,
                         <<"message">> := <<"the value 'abc' on tele/webplug/POWER_W is not a "
                                            "number", _/binary>>} <- Now] =/= []
          end),
    {200, #{<<"restarted">> := true}} =
        change(put, Path ++ "/description", #{xml => mqtt_xml(<<"Plug02">>)}),
    until(fun() ->
                  case ?T:get(Path) of
                      {200, #{<<"components">> := [#{<<"id">> := <<"Plug02">>}]}} -> true;
                      _ -> false
                  end
          end),
    %% The pairing sees the new component.
    until(fun() ->
                  {200, #{<<"entities">> := Es}} = ?T:get("/api/pairings/" ++ binary_to_list(?MQTT_PAIRING)),
                  [<<"Plug02">>] =:= [C || #{<<"entity">> := E,
                                             <<"components">> := [#{<<"id">> := C}]} <- Es,
                                           E =:= ?MQTT_AV]
          end),
    Broken = binary:replace(mqtt_xml(<<"Plug03">>), <<"<MqttExpect>raw:ON</MqttExpect>">>,
                            <<"<MqttExpect>sometimes</MqttExpect>">>),
    {400, #{<<"field">> := <<"xml">>, <<"message">> := _}} =
        change(put, Path ++ "/description", #{xml => Broken}),
    {200, #{<<"components">> := [#{<<"id">> := <<"Plug02">>}]}} = ?T:get(Path),
    {404, #{<<"field">> := <<"entity_id">>}} = ?T:get("/api/mqtt_avatars/nope"),
    {404, _} = ?T:get("/api/mqtt_avatars/nope/problems"),
    {404, _} = change(put, "/api/mqtt_avatars/nope/description", #{xml => <<"<x/>">>}),
    {400, #{<<"error">> := <<"bad_request">>}} =
        change(put, "/api/mqtt_avatars/nope/description", #{colour => 1}),
    {400, #{<<"field">> := <<"overrides">>}} =
        change(put, "/api/mqtt_avatars/nope/description", #{overrides => #{<<"d">> => #{skip => 3}}}).

%% WoT Avatars: the list with the keeper's state, one's problems (what its
%% TD left out: a CoAP form), and an unknown one's.
wot_avatar_routes(_Config) ->
    Path = "/api/wot_avatars/" ++ binary_to_list(?WOT_AV) ++ "/problems",
    until(fun() -> element(1, ?T:get(Path)) =:= 200 end),
    {200, L} = ?T:get("/api/wot_avatars"),
    [#{<<"state">> := <<"running">>, <<"running">> := true, <<"starts">> := 1, <<"crashes">> := 0}] =
        [A || #{<<"entity_id">> := E} = A <- L, E =:= ?WOT_AV],
    {200, [#{<<"what">> := <<"unsupported_scheme">>, <<"affordance">> := <<"blink">>,
             <<"message">> := <<"a form uses coap", _/binary>>}]} = ?T:get(Path),
    {404, #{<<"field">> := <<"entity_id">>, <<"message">> := <<"no WoT Avatar nope on this node">>}} =
        ?T:get("/api/wot_avatars/nope/problems").

%% The OpenAPI document is served and is JSON.
openapi_document(_Config) ->
    {200, #{<<"openapi">> := <<"3.0", _/binary>>, <<"paths">> := Paths}} = ?T:get("/api/openapi.json"),
    [true = maps:is_key(P, Paths) || {_, P0, _, _} <- evatar_web_router:routes(),
                                     P <- [openapi_path(P0)]].

%% The live server's answers, good and bad, checked against
%% priv/openapi.json by a real validator: Python's openapi-core (from PyPI,
%% in a venv this test makes under _build, as clients/python/run-tests.sh
%% does), which also validates the document itself. Real answers made wrong
%% on purpose then go through the same check and must all be refused.
live_answers_match_openapi(Config) ->
    Python = venv(),
    Script = filename:join(?config(data_dir, Config), "check_openapi.py"),
    Spec = filename:join(code:priv_dir(evatar_web), "openapi.json"),
    {Status, Out} = run(Python, [Script, Spec, ?T:url("/"), binary_to_list(?PAIRING),
                                 binary_to_list(?MQTT_AV), binary_to_list(?WOT_AV)],
                        [{"EVATAR_TOKEN", binary_to_list(?TOKEN)}]),
    ct:pal("~ts", [Out]),
    0 = Status,
    {match, _} = re:run(Out, "(\\d+) answers checked.*, 0 not matching"),
    %% The same checker refuses answers made wrong on purpose: it can fail.
    {match, [N]} = re:run(Out, "(\\d+) wrong answers given to the checker, 0 accepted",
                          [{capture, all_but_first, list}]),
    true = list_to_integer(N) > 0.

venv() ->
    Src = proplists:get_value(source, evatar_web:module_info(compile)),
    Root = filename:dirname(filename:dirname(filename:dirname(filename:dirname(Src)))),
    Venv = case os:getenv("EVATAR_OPENAPI_VENV") of
               V when is_list(V), V =/= "" -> V;
               _ -> filename:join([Root, "_build", "openapi-venv"])
           end,
    Python = filename:join([Venv, "bin", "python"]),
    case filelib:is_regular(filename:join([Venv, "bin", "openapi-core.ok"])) of
        true ->
            ok;
        false ->
            {0, _} = run(os:find_executable("python3"), ["-m", "venv", Venv], []),
            {0, _} = run(Python, ["-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                                  "openapi-core"], []),
            ok = file:write_file(filename:join([Venv, "bin", "openapi-core.ok"]), <<>>)
    end,
    Python.

run(Exe, Args, Env) ->
    Port = open_port({spawn_executable, Exe}, [{args, Args}, {env, Env}, exit_status, binary,
                                               stderr_to_stdout]),
    collect(Port, []).

collect(Port, Acc) ->
    receive
        {Port, {data, D}} -> collect(Port, [Acc, D]);
        {Port, {exit_status, S}} -> {S, unicode:characters_to_list(iolist_to_binary(Acc))}
    after evatar_test_time:ms(300000) -> ct:fail({no_exit, iolist_to_binary(Acc)})
    end.

%% ---------------------------------------------------------------------------

openapi_path(P) ->
    iolist_to_binary(lists:join("/", [case S of
                                          <<":", N/binary>> -> [${, N, $}];
                                          _ -> S
                                      end || S <- binary:split(P, <<"/">>, [global])])).

auth(Token) -> {"authorization", "Bearer " ++ binary_to_list(Token)}.

json(Term) -> binary_to_list(evatar_json:encode(Term)).

change(Method, Path, none) ->
    ?T:request(Method, Path, [auth(?TOKEN)], none);
change(Method, Path, Body) ->
    ?T:request(Method, Path, [auth(?TOKEN)], json(Body)).


start_mosquitto(Dir) ->
    {ok, L} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}]),
    {ok, Port} = inet:port(L),
    ok = gen_tcp:close(L),
    Conf = filename:join(Dir, "mosquitto.conf"),
    ok = file:write_file(Conf, io_lib:format("listener ~b 127.0.0.1~nallow_anonymous true~n", [Port])),
    P = open_port({spawn_executable, os:find_executable("mosquitto", "/usr/sbin:/usr/bin")},
                  [{args, ["-c", Conf]}, exit_status, stderr_to_stdout]),
    until(fun() ->
                  case gen_tcp:connect({127, 0, 0, 1}, Port, []) of
                      {ok, S} -> ok = gen_tcp:close(S), true;
                      {error, _} -> false
                  end
          end),
    {os_pid, OsPid} = erlang:port_info(P, os_pid),
    {P, Port, OsPid}.

mqtt_xml(Component) ->
    iolist_to_binary(
      ["<bil:description xmlns:bil=\"urn:evatar:bil:1\"><bil:context>"
       "<EntityID>", ?MQTT_AV, "</EntityID><APIName>MQTT</APIName><EntityType>Avatar</EntityType>"
       "<Context>x</Context></bil:context><bil:types><bil:Component>"
       "<ComponentID>", Component, "</ComponentID>"
       "<Service><ServiceCategory>ACTUATOR</ServiceCategory><ServiceType>TurnLightOn</ServiceType>"
       "<ServiceParameters><Light>yes</Light><Room>kitchen</Room>"
       "<MqttCommandTopic>cmnd/webplug/POWER</MqttCommandTopic>"
       "<MqttStateTopic>stat/webplug/POWER</MqttStateTopic>"
       "<MqttCommand>raw:ON</MqttCommand><MqttExpect>raw:ON</MqttExpect>"
       "<MqttValue>Light=raw</MqttValue><MqttMap>ON=on OFF=off</MqttMap>"
       "</ServiceParameters></Service>"
       "<Consumes><ServiceCategory>SENSOR</ServiceCategory><ServiceType>Power</ServiceType>"
       "<ServiceParameters><MqttStateTopic>tele/webplug/POWER_W</MqttStateTopic>"
       "<MqttValue>Power=raw</MqttValue><MqttNumeric>Power</MqttNumeric>"
       "</ServiceParameters></Consumes></bil:Component></bil:types></bil:description>"]).

entry(Cat, Type, Params) -> #{category => Cat, type => Type, parameters => Params}.

va_description() ->
    #{entity_id => <<"va">>, api_name => <<"TEST VA">>, entity_type => agent,
      context => <<"EmulatorDescription">>,
      components => [#{id => <<"LightEmulator01">>,
                       services => [entry(<<"BEHAVIOUR">>, <<"Light">>, [])],
                       consumes => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>, []),
                                    entry(<<"ACTUATOR">>, <<"Dim">>, [{<<"Room">>, <<"kitchen">>}]),
                                    entry(<<"ACTUATOR">>, <<"OpenDoor">>, [])]}]}.

avatar_description() ->
    #{entity_id => <<"av">>, api_name => <<"TEST AVATAR">>, entity_type => avatar,
      context => <<"ActuatorDescription">>,
      components => [#{id => <<"Light01">>, services => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>, [])],
                       consumes => []},
                     #{id => <<"Dimmer01">>,
                       services => [entry(<<"ACTUATOR">>, <<"Dim">>, [{<<"Room">>, <<"hall">>}])],
                       consumes => []}]}.
