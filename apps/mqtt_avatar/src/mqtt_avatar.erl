%% @doc Public API of the MQTT Avatar: an Avatar whose components are MQTT
%% devices (Tasmota, Shelly, zigbee2mqtt, ESPHome, or anything that speaks
%% the same conventions). It finds devices through Home Assistant discovery
%% and zigbee2mqtt's device list, or reads a hand-written BIL description,
%% and joins EVATAR as role `avatar'. docs/mqtt.md is the guide; every
%% other mqtt_avatar_* module is internal.
-module(mqtt_avatar).

-export([start/1, start_link/1, stop/1, await_ready/2, keep/1, unkeep/1, kept/0, check_opts/1,
         reconfigure/2]).
-export([description/1, public_description/1, description_xml/1, print_description/1,
         problems/1, print_problems/1, status/1]).
-export([discover/2, generate/2, read_description/1, check/1]).
-export([discovery_max_device_list/0]).

-export_type([opts/0, avatar/0, problem/0]).

-type avatar() :: pid().
%% `mqtt': the broker, as for mqtt_client (host, port, and optionally
%% username, password, tls, client_id...). `evatar': where to join, or
%% `false' to discover without joining. `description': hand-written
%% components (a term, BIL XML, or `{file, Path}'). `discovery': prefixes to
%% listen on, or `false'. `overrides': see docs/mqtt.md section 5. Times in
%% ms: `settle' (quiet time that ends a discovery burst, 500),
%% `discovery_wait' (longest wait before joining anyway, 3000),
%% `echo_timeout' (5000), `retry' (first delay before joining again, 200).
%% `timestamp_field': a top-level JSON field of state payloads holding the
%% reading's time (ms since 1970), used as the signals' Timestamp.
%% `birth': Home Assistant's birth message, published after every MQTT
%% connection (default `#{topic => <<"homeassistant/status">>, payload =>
%% <<"online">>}'; `false' publishes none).
-type opts() :: #{entity_id := binary(),
                  mqtt := map(),
                  evatar => false | #{endpoints := [agent_bridge_client:endpoint()],
                                      pairing := binary(),
                                      credential => binary()},
                  description => bil:description() | binary() | {file, file:filename()},
                  discovery => false | mqtt_avatar_discovery:opts(),
                  overrides => mqtt_avatar_generate:overrides(),
                  api_name => binary(),
                  settle => non_neg_integer(),
                  discovery_wait => non_neg_integer(),
                  echo_timeout => non_neg_integer(),
                  retry => pos_integer(),
                  timestamp_field => binary(),
                  birth => false | #{topic => binary(), payload => binary()},
                  restart => restart_backoff:opts(),
                  static_components => [bil:component()]}.
%% Every problem has `what' (an atom from a fixed set) and `message' (a
%% sentence); most have `topic' or `component'.
-type problem() :: #{what := atom(), message := binary(), atom() => term()}.

-define(CALL_TIMEOUT, 15000).

%% ---------------------------------------------------------------------------
%% Running an Avatar
%% ---------------------------------------------------------------------------

%% @doc Starts an MQTT Avatar under the `mqtt_avatar' application's
%% supervisor. Returns at once; `await_ready/2' waits until it has joined.
%% A hand-written description with mistakes is refused here, with every
%% problem listed.
-spec start(opts()) -> {ok, avatar()} | {error, [problem()] | term()}.
start(Opts) ->
    case prepare(Opts) of
        {ok, Opts1} -> mqtt_avatar_sup:start_child(Opts1);
        {error, _} = Error -> Error
    end.

%% @doc Keeps an MQTT Avatar running under the application's supervisor:
%% when it exits it is started again after a delay that doubles from 1 s
%% to 60 s (`restart' => #{min_ms, max_ms, stable_after_ms, loop_after}
%% changes the policy, restart_backoff), and a crash loop is logged
%% (`what => crash_loop'). Stopping the Avatar with `stop/1', or
%% `unkeep/1', ends it for good. One kept Avatar per entity id. Returns the
%% keeper; `kept/0' tells the Avatar's own pid.
-spec keep(opts()) -> {ok, pid()} | {error, already_kept | [problem()] | term()}.
keep(Opts) ->
    case prepare(Opts) of
        {ok, _} -> mqtt_avatar_sup:keep(Opts);
        {error, _} = Error -> Error
    end.

%% @doc Stops a kept Avatar (Bye, DISCONNECT) and forgets it.
-spec unkeep(binary()) -> ok | {error, not_found}.
unkeep(EntityId) ->
    mqtt_avatar_sup:unkeep(EntityId).

%% @doc The kept Avatars: entity id, `running' or `waiting' (to start
%% again), the Avatar's pid while running, how many times it was started,
%% short runs in a row (`crashes'), and the delay the next one would get.
-spec kept() -> [mqtt_avatar_keeper:status()].
kept() ->
    [mqtt_avatar_keeper:status(K) || {_, K} <- mqtt_avatar_sup:keepers()].

%% @doc Changes a kept Avatar's `description' (hand-written, replacing
%% the generated one) or `overrides' (how devices become components): the
%% options are checked as by check_opts/1, then the Avatar stops (Bye,
%% DISCONNECT) and starts again with them, describing itself anew. They
%% last until the node restarts (the configuration file's stay as written).
-spec reconfigure(binary(), #{description => binary() | bil:description(),
                              overrides => mqtt_avatar_generate:overrides()}) ->
          ok | {error, not_found | [problem()]}.
reconfigure(EntityId, Changes) ->
    case [K || {E, K} <- mqtt_avatar_sup:keepers(), E =:= EntityId] of
        [Keeper] -> mqtt_avatar_keeper:reconfigure(Keeper, maps:with([description, overrides], Changes));
        [] -> {error, not_found}
    end.

%% @doc The `discovery' option `max_device_list_size' (zigbee2mqtt's
%% bridge/devices): its default and the largest value accepted, in bytes
%% (docs/mqtt.md section 6).
-spec discovery_max_device_list() -> {Default :: pos_integer(), Limit :: pos_integer()}.
discovery_max_device_list() -> mqtt_avatar_discovery:max_device_list_limit().

%% @doc Checks options as `start/1' would (the required keys, a
%% hand-written description and its file) without starting anything.
-spec check_opts(opts()) -> ok | {error, [problem()]}.
check_opts(Opts) ->
    case prepare(Opts) of
        {ok, _} -> ok;
        {error, _} = Error -> Error
    end.

%% @doc Like `start/1', linked to the caller and outside the supervisor.
-spec start_link(opts()) -> {ok, avatar()} | {error, [problem()] | term()}.
start_link(Opts) ->
    case prepare(Opts) of
        {ok, Opts1} -> mqtt_avatar_fsm:start_link(Opts1);
        {error, _} = Error -> Error
    end.

%% @doc Leaves EVATAR (Bye) and the broker (DISCONNECT), then stops.
-spec stop(avatar()) -> ok.
stop(Avatar) ->
    gen_statem:call(Avatar, stop, ?CALL_TIMEOUT).

%% @doc Waits until the Avatar has joined EVATAR and described itself
%% (without `evatar': until discovery has settled).
-spec await_ready(avatar(), timeout()) -> ok | {error, timeout}.
await_ready(Avatar, Timeout) ->
    try gen_statem:call(Avatar, await_ready, Timeout)
    catch exit:{timeout, _} -> {error, timeout}
    end.

%% ---------------------------------------------------------------------------
%% Inspection
%% ---------------------------------------------------------------------------

%% @doc The full description, with the `Mqtt*' parameters: what a person
%% checks, edits and passes back as `description'.
-spec description(avatar()) -> bil:description().
description(Avatar) ->
    gen_statem:call(Avatar, description, ?CALL_TIMEOUT).

%% @doc The description EVATAR receives: without the `Mqtt*' parameters.
-spec public_description(avatar() | bil:description()) -> bil:description().
public_description(Avatar) when is_pid(Avatar) ->
    mqtt_avatar_spec:public(description(Avatar));
public_description(Description) ->
    mqtt_avatar_spec:public(Description).

%% @doc The full description as BIL XML, one element per line.
-spec description_xml(avatar() | bil:description()) -> binary().
description_xml(Avatar) when is_pid(Avatar) ->
    description_xml(description(Avatar));
description_xml(Description) ->
    indent(iolist_to_binary(bil:encode_description(Description))).

%% @doc Prints the full description as BIL XML, for a person to check or
%% to save and edit (`mqtt_avatar:print_description(A)' in a shell).
-spec print_description(avatar() | bil:description()) -> ok.
print_description(AvatarOrDescription) ->
    io:put_chars([description_xml(AvatarOrDescription), $\n]).

%% @doc Recent problems, oldest first (at most 100): malformed discovery
%% messages and payloads, devices that did not echo a command, EVATAR's
%% refusals. Each is also logged.
-spec problems(avatar()) -> [problem()].
problems(Avatar) ->
    gen_statem:call(Avatar, problems, ?CALL_TIMEOUT).

%% @doc Prints `problems/1', one line each.
-spec print_problems(avatar()) -> ok.
print_problems(Avatar) ->
    lists:foreach(fun(#{what := W, message := M} = P) ->
                          Where = [[" ", K, "=", V] || {K, V} <- [{"topic", maps:get(topic, P, undefined)},
                                                                 {"component", maps:get(component, P, undefined)}],
                                                      is_binary(V)],
                          io:format("~s~s: ~ts~n", [W, Where, M])
                  end, problems(Avatar)).

%% @doc The state of the sessions and devices: `state', `mqtt' and `evatar'
%% (up/down), `broker' (`host', as the options give it, and `port'),
%% `components', `availability', `last_values', `pending', `subscriptions'.
-spec status(avatar()) -> map().
status(Avatar) ->
    gen_statem:call(Avatar, status, ?CALL_TIMEOUT).

%% ---------------------------------------------------------------------------
%% Discovery without joining
%% ---------------------------------------------------------------------------

%% @doc Connects to the broker, listens to discovery for `Wait' ms (or
%% until it settles) and returns the description that would be sent, with
%% the problems met, without joining EVATAR. `Opts' as for `start/1'
%% (`evatar' is ignored; `entity_id' defaults to `mqtt-avatar').
-spec discover(map(), timeout()) -> {ok, bil:description(), [problem()]} | {error, term()}.
discover(Opts, Wait) ->
    Opts1 = maps:merge(#{entity_id => <<"mqtt-avatar">>, discovery => #{}, discovery_wait => Wait},
                       Opts),
    case start_link(Opts1#{evatar => false}) of
        {ok, A} ->
            Result = case await_ready(A, Wait + 5000) of
                         ok -> {ok, description(A), problems(A)};
                         {error, timeout} -> {error, broker_unreachable}
                     end,
            ok = stop(A),
            Result;
        {error, _} = Error ->
            Error
    end.

%% @doc Pure: the description generated from discovery messages given as
%% `{Topic, Payload}' pairs (for example captured with
%% `mosquitto_sub -v -t "homeassistant/#"'), with the problems they give.
%% `Opts': `entity_id', `discovery', `overrides', `description'.
-spec generate([{binary(), binary()}], map()) -> {bil:description(), [problem()]}.
generate(Messages, Opts) ->
    {Discovery, Problems} =
        lists:foldl(fun({Topic, Payload}, {S, Ps}) ->
                            case mqtt_avatar_discovery:handle(Topic, Payload, S) of
                                ignore -> {S, [[#{what => not_discovery, topic => Topic,
                                                  message => <<"not a discovery topic">>}] | Ps]};
                                {_, S1, P} -> {S1, [P | Ps]}
                            end
                    end, {mqtt_avatar_discovery:new(maps:get(discovery, Opts, #{})), []}, Messages),
    Static = case static(Opts) of
                 {ok, C} -> C;
                 {error, _} -> []
             end,
    mqtt_avatar_generate:description(
      #{entity_id => maps:get(entity_id, Opts, <<"mqtt-avatar">>), static => Static,
        overrides => maps:get(overrides, Opts, #{})},
      mqtt_avatar_discovery:devices(Discovery), lists:append(lists:reverse(Problems))).

%% @doc Reads a description file (BIL XML, as printed and edited).
-spec read_description(file:filename()) -> {ok, bil:description()} | {error, binary()}.
read_description(File) ->
    case file:read_file(File) of
        {ok, Bin} ->
            case bil:parse_description(Bin) of
                {ok, D} -> {ok, D};
                {error, R} -> {error, bil:format_error(R)}
            end;
        {error, Reason} ->
            {error, iolist_to_binary(io_lib:format("~ts: ~ts", [File, file:format_error(Reason)]))}
    end.

%% @doc Checks the `Mqtt*' parameters of a description (docs/mqtt.md
%% section 3) and that it is valid BIL.
-spec check(bil:description()) -> ok | {error, [problem()]}.
check(Description) ->
    case mqtt_avatar_spec:from_description(Description) of
        {ok, _} ->
            case mqtt_avatar_spec:round_trip(Description) of
                ok -> ok;
                {error, M} -> {error, [#{what => bad_description, message => M}]}
            end;
        {error, Problems} ->
            {error, [P#{what => bad_mqtt_parameters, message => mqtt_avatar_spec:format_problem(P)}
                     || P <- Problems]}
    end.

%% ---------------------------------------------------------------------------
%% Internals
%% ---------------------------------------------------------------------------

prepare(#{entity_id := Id, mqtt := #{host := _, port := _}} = Opts) when is_binary(Id), Id =/= <<>> ->
    case {birth_ok(maps:get(birth, Opts, false)), static(Opts)} of
        {false, _} ->
            {error, [#{what => bad_options,
                       message => <<"birth must be false or #{topic, payload}: a topic without "
                                    "+ or # and a binary payload">>}]};
        {true, Static} ->
            prepared(Static, Opts)
    end;
prepare(_Opts) ->
    {error, [#{what => bad_options,
               message => <<"entity_id (a non-empty binary) and mqtt => #{host, port} are required">>}]}.

birth_ok(false) ->
    true;
birth_ok(#{} = B) ->
    Topic = maps:get(topic, B, <<"homeassistant/status">>),
    is_binary(Topic) andalso Topic =/= <<>>
        andalso binary:match(Topic, [<<"+">>, <<"#">>, <<0>>]) =:= nomatch
        andalso is_binary(maps:get(payload, B, <<>>))
        andalso maps:size(maps:without([topic, payload], B)) =:= 0;
birth_ok(_) ->
    false.

prepared(Static, Opts) ->
    case Static of
        {ok, Components} -> {ok, maps:remove(description, Opts#{static_components => Components})};
        {error, _} = Error -> Error
    end.

static(Opts) ->
    case maps:get(description, Opts, undefined) of
        undefined ->
            {ok, []};
        {file, File} ->
            case read_description(File) of
                {ok, D} -> static_checked(D);
                {error, M} -> {error, [#{what => bad_description, message => M}]}
            end;
        Xml when is_binary(Xml) ->
            case bil:parse_description(Xml) of
                {ok, D} -> static_checked(D);
                {error, R} -> {error, [#{what => bad_description, message => bil:format_error(R)}]}
            end;
        #{components := _} = D ->
            static_checked(D)
    end.

static_checked(#{components := Components} = D) ->
    case check(D) of
        ok -> {ok, Components};
        {error, _} = Error -> Error
    end.

%% One element per line, nested by two spaces: bil's encoder writes one
%% line, which a person cannot edit comfortably.
indent(Xml) ->
    Parts = re:split(Xml, <<"(<[^>]*>)">>, [{return, binary}, trim]),
    indent([P || P <- Parts, P =/= <<>>], 0, []).

indent([], _Depth, Acc) ->
    iolist_to_binary(lists:reverse(Acc));
indent([<<"<?", _/binary>> = Decl | Rest], Depth, Acc) ->
    indent(Rest, Depth, [[Decl, $\n] | Acc]);
indent([<<"</", _/binary>> = Close | Rest], Depth, Acc) ->
    indent(Rest, Depth - 1, [[pad(Depth - 1), Close, $\n] | Acc]);
indent([<<"<", _/binary>> = Open, Text, <<"</", _/binary>> = Close | Rest], Depth, Acc)
  when binary_part(Text, 0, 1) =/= <<"<">> ->
    indent(Rest, Depth, [[pad(Depth), Open, Text, Close, $\n] | Acc]);
indent([<<"<", _/binary>> = Open | Rest], Depth, Acc) ->
    case binary:last(Open) of
        $> when binary_part(Open, byte_size(Open) - 2, 2) =:= <<"/>">> ->
            indent(Rest, Depth, [[pad(Depth), Open, $\n] | Acc]);
        _ ->
            indent(Rest, Depth + 1, [[pad(Depth), Open, $\n] | Acc])
    end;
indent([Text | Rest], Depth, Acc) ->
    case string:trim(Text) of
        <<>> -> indent(Rest, Depth, Acc);
        T -> indent(Rest, Depth, [[pad(Depth), T, $\n] | Acc])
    end.

pad(N) -> binary:copy(<<"  ">>, max(0, N)).
