%% @doc Internal. Reads the MQTT side of an MQTT Avatar's BIL description:
%% the reserved `Mqtt*' service parameters (docs/mqtt.md section 3) become a
%% runtime spec (which topics to subscribe to, what to publish for each
%% service, how payloads map to BIL parameters), and are stripped from the
%% public description that EVATAR binds. Pure functions only.
-module(mqtt_avatar_spec).

-export([from_description/1, of_components/1, public/1, is_reserved/1, reserved_names/0,
         parse_source/1, keyword/1, format_problem/1, round_trip/1, is_name/1]).

-export_type([spec/0, component/0, service/0, stream/0, availability/0, availability_entry/0,
              availability_mode/0, source/0, expect/0, problem/0, check/0, code/0]).

%% `raw': the whole payload as text; `{json, Path}': a field of the JSON
%% payload ([] is the whole value).
%% `template': the entry's MqttValueTemplate, evaluated on the payload;
%% `{template, Text}' is how discovery hands such a template to the
%% generator (mqtt_avatar_part writes it as `template' and the text).
-type source() :: raw | {json, [binary()]} | template | {template, binary()}.
%% `{template, Text}': the entry's MqttValueTemplate renders Text.
-type match() :: {raw, binary()} | {json, [binary()], binary()} | {template, binary()}.
-type expect() :: none | any | match() | light.
%% How a state message becomes BIL parameters.
%% `scale': MqttScale, `{Param, Lo, Hi}': the device writes Param in
%% Lo..Hi, BIL carries it as a percentage (HA's fan speed_range).
%% `template_text': the MqttValueTemplate as written, for problems.
-type mapping() :: #{template => mqtt_avatar_template:template(),
                     template_text => binary(),
                     scale => [{binary(), integer(), integer()}],
                     values := [{binary(), source()}],
                     attributes := boolean(),
                     map := [{binary(), binary()}]}.
-type service() :: #{category := binary(),
                     type := binary(),
                     static := [bil:parameter()],
                     kind := command | read | unsupported,
                     command_topic => binary(),
                     command => {raw, binary()} | {json, evatar_json:json()}
                              | {light, on | off},
                     light => mqtt_avatar_light:light(),
                     args => [{binary(), [binary()]}],
                     state_topic => binary() | undefined,
                     expect => expect(),
                     progress => match() | undefined,
                     mapping => mapping(),
                     checks => [{binary(), check()}],
                     command_template => mqtt_avatar_template:template() | undefined,
                     code => code() | undefined}.
%% What a request parameter must be (MqttArgCheck): present, and within
%% the range or one of the values.
-type check() :: present | {range, number(), number()} | {one_of, [binary()]}.
%% A code the request must carry (MqttCode): its PBKDF2-SHA256 hash.
-type code() :: {pbkdf2_sha256, pos_integer(), binary(), binary()}.
-type stream() :: #{category := binary(),
                    type := binary(),
                    static := [bil:parameter()],
                    topic := binary(),
                    context := sensor_data | event,
                    on_change := boolean(),
                    numeric := [binary()],
                    mapping := mapping()}.
%% `{template, Text}': Home Assistant's availability_template, rendered
%% by mqtt_avatar_template and compared with the payloads.
-type availability_entry() :: #{topic := binary(),
                                online := binary(),
                                offline := binary(),
                                value := source() | {template, binary()}}.
%% Home Assistant's `availability_mode': how the entries' payloads make the
%% device's availability (docs/mqtt.md section 3.1).
-type availability_mode() :: all | any | latest.
-type availability() :: #{mode := availability_mode(),
                          entries := [availability_entry(), ...]}.
-type component() :: #{id := binary(),
                       services := [service()],
                       streams := [stream()],
                       feedback := {binary(), binary()},
                       read_body := {binary(), binary()},
                       room := binary() | undefined,
                       availability := availability() | undefined}.
-type spec() :: #{components := [component()],
                  topics := [binary()]}.
-type problem() :: #{component := binary(),
                     entry := binary(),
                     parameter => binary(),
                     message := binary()}.

%% Inherited within a component: an entry without one of these takes the
%% first value written on another entry of the same component.
-define(IS_HEX(C), ((C >= $0 andalso C =< $9) orelse (C >= $a andalso C =< $f)
                    orelse (C >= $A andalso C =< $F))).
-define(INHERITED, [<<"MqttStateTopic">>, <<"MqttCommandTopic">>, <<"MqttAvailabilityMode">>
                    | [<<AvName/binary, AvSuffix/binary>>
                       || AvSuffix <- [<<>> | [integer_to_binary(I)
                                               || I <- lists:seq(2, ?MAX_AVAILABILITY)]],
                          AvName <- ?AVAILABILITY_NAMES]]).
%% One availability entry: its topic, payloads and where the payload is.
%% The first entry's names are bare, the others' end in 2 .. 8 (HA's
%% `availability' list, in order).
-define(AVAILABILITY_NAMES, [<<"MqttAvailabilityTopic">>, <<"MqttPayloadAvailable">>,
                             <<"MqttPayloadNotAvailable">>, <<"MqttAvailabilityValue">>]).
-define(MAX_AVAILABILITY, 8).
-define(ENTRY_ONLY, [<<"MqttCommand">>, <<"MqttCommandArgs">>, <<"MqttExpect">>,
                     <<"MqttExtra">>, <<"MqttArgCheck">>, <<"MqttCode">>,
                     <<"MqttValueTemplate">>, <<"MqttCommandTemplate">>,
                     <<"MqttProgress">>, <<"MqttValue">>, <<"MqttAttributes">>,
                     <<"MqttMap">>, <<"MqttContext">>, <<"MqttOnChange">>, <<"MqttLight">>,
                     <<"MqttScale">>, <<"MqttNumeric">>]).
%% What only a command service reads.
-define(COMMAND_ONLY, [<<"MqttCommandArgs">>, <<"MqttExpect">>, <<"MqttProgress">>,
                       <<"MqttArgCheck">>, <<"MqttCode">>, <<"MqttCommandTemplate">>]).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Every reserved parameter name.
-spec reserved_names() -> [binary()].
reserved_names() -> ?INHERITED ++ ?ENTRY_ONLY.

%% @doc True for parameter names reserved for the MQTT mapping (every name
%% starting with `Mqtt'); they never reach EVATAR.
-spec is_reserved(binary()) -> boolean().
is_reserved(<<"Mqtt", _/binary>>) -> true;
is_reserved(_) -> false.

%% @doc The description EVATAR sees: the same, without reserved parameters.
-spec public(bil:description()) -> bil:description().
public(#{components := Components} = D) ->
    Strip = fun(#{parameters := Ps} = E) ->
                    E#{parameters := [P || {N, _} = P <- Ps, not is_reserved(N)]}
            end,
    D#{components := [C#{services := [Strip(E) || E <- S], consumes := [Strip(E) || E <- Co]}
                      || #{services := S, consumes := Co} = C <- Components]}.

%% @doc Builds the runtime spec, or lists every problem found.
-spec from_description(#{components := [bil:component()], atom() => term()}) ->
          {ok, spec()} | {error, [problem()]}.
from_description(#{components := Components}) ->
    Results = [component(C) || C <- Components],
    case lists:append([P || {error, P} <- Results]) of
        [] ->
            {ok, of_components([S || {ok, S} <- Results])};
        Problems ->
            {error, Problems}
    end.

%% @doc The spec of components read one by one (each the only component
%% of a `from_description/1' spec), in order.
-spec of_components([component()]) -> spec().
of_components(Specs) ->
    #{components => Specs, topics => topics(Specs)}.

%% @doc Parses a payload source: `raw' or `json:a.b.c' (`json:' alone is the
%% whole JSON value).
-spec parse_source(binary()) -> {ok, source()} | error.
parse_source(<<"raw">>) -> {ok, raw};
parse_source(<<"template">>) -> {ok, template};
parse_source(<<"json:", Path/binary>>) -> path(Path);
parse_source(_) -> error.

%% @doc The keyword BIL binding compares names with (docs/bil.md section 4,
%% rule 1), for ASCII names: lower case, letters and digits only.
-spec keyword(binary()) -> binary().
keyword(Bin) ->
    Lower = string:casefold(unicode:characters_to_nfc_binary(Bin)),
    << <<C/utf8>> || <<C/utf8>> <= Lower, is_alnum(C) >>.

%% @doc Checks that a description can be written as BIL and read back
%% unchanged by EVATAR's parser.
-spec round_trip(bil:description()) -> ok | {error, binary()}.
round_trip(#{components := Components} = D) ->
    Names = [N || #{services := S, consumes := C} <- Components, #{parameters := Ps} <- S ++ C,
                  {N, _} <- Ps],
    case [N || N <- Names, not is_name(N)] of
        [] ->
            case bil:parse_description(iolist_to_binary(bil:encode_description(D))) of
                {ok, _} -> ok;
                {error, R} -> {error, bil:format_error(R)}
            end;
        [Bad | _] ->
            {error, <<"parameter name ", Bad/binary, " cannot be an XML element name">>}
    end.

%% @doc One line for a person.
-spec format_problem(problem()) -> binary().
format_problem(#{component := C, entry := E, message := M} = P) ->
    Param = case P of
                #{parameter := N} -> [" ", N];
                _ -> []
            end,
    iolist_to_binary(["component ", C, ", ", E, Param, ": ", M]).

%% ---------------------------------------------------------------------------
%% Components
%% ---------------------------------------------------------------------------

component(#{id := Id, services := Services, consumes := Consumes}) ->
    Inherited = inherited(Services ++ Consumes),
    Check = [unknown_names(Id, E, What) || {What, E} <- [{"Service", S} || S <- Services]
                                                            ++ [{"Consumes", C} || C <- Consumes]],
    StreamResults = [stream(Id, E, Inherited) || E <- Consumes, has(<<"MqttValue">>, E)
                                                     orelse has(<<"MqttAttributes">>, E)],
    Streams = [S || {ok, S} <- StreamResults],
    ServiceResults = [service(Id, E, Inherited, Streams =/= []) || E <- Services],
    AvailResult = availability(Id, Inherited),
    Problems = lists:append(Check) ++ [P || {error, Ps} <- StreamResults ++ ServiceResults ++ [AvailResult],
                                            P <- Ps],
    case Problems of
        [] ->
            {ok, Avail} = AvailResult,
            {ok, #{id => Id,
                   services => [S || {ok, S} <- ServiceResults],
                   streams => Streams,
                   feedback => feedback_body(Consumes),
                   read_body => read_body(Consumes),
                   room => room(Services ++ Consumes),
                   availability => Avail}};
        _ ->
            {error, Problems}
    end.

inherited(Entries) ->
    lists:foldl(fun(#{parameters := Ps}, Acc) ->
                        lists:foldl(fun({N, V}, A) ->
                                            case is_inherited(N) andalso
                                                not maps:is_key(N, A) of
                                                true -> A#{N => V};
                                                false -> A
                                            end
                                    end, Acc, Ps)
                end, #{}, Entries).

%% Whether a parameter is one a component's entries share (?INHERITED),
%% without building that list for every parameter.
is_inherited(<<"MqttStateTopic">>) -> true;
is_inherited(<<"MqttCommandTopic">>) -> true;
is_inherited(<<"MqttAvailabilityMode">>) -> true;
is_inherited(<<"MqttAvailabilityTopic", S/binary>>) -> is_availability_suffix(S);
is_inherited(<<"MqttPayloadAvailable", S/binary>>) -> is_availability_suffix(S);
is_inherited(<<"MqttPayloadNotAvailable", S/binary>>) -> is_availability_suffix(S);
is_inherited(<<"MqttAvailabilityValue", S/binary>>) -> is_availability_suffix(S);
is_inherited(_) -> false.

is_availability_suffix(<<>>) -> true;
is_availability_suffix(<<D>>) -> D >= $2 andalso D - $0 =< ?MAX_AVAILABILITY;
is_availability_suffix(_) -> false.

unknown_names(Id, #{parameters := Ps} = E, What) ->
    [problem(Id, E, What, N, <<"unknown reserved parameter (see docs/mqtt.md section 3)">>)
     || {N, _} <- Ps, is_reserved(N), not is_inherited(N), not lists:member(N, ?ENTRY_ONLY)].

%% An entry's own value, else the component's.
get(Name, #{parameters := Ps}, Inherited) ->
    case lists:keyfind(Name, 1, Ps) of
        {_, V} -> V;
        false -> maps:get(Name, Inherited, undefined)
    end.

get(Name, #{parameters := Ps}) ->
    case lists:keyfind(Name, 1, Ps) of
        {_, V} -> V;
        false -> undefined
    end.

has(Name, E) -> get(Name, E) =/= undefined.

static(#{parameters := Ps} = E) ->
    [{N, V} || {N, V} <- Ps, not is_reserved(N),
               not lists:member(keyword(V), [<<"yes">>, <<"no">>, <<"any">>])]
        ++ case get(<<"MqttExtra">>, E) of
               undefined -> [];
               Text -> [{N, V} || [N, V] <- [binary:split(T, <<"=">>) || T <- tokens(Text)]]
           end.

%% MqttExtra: Name=Value tokens (checked here, read by static/1).
extra(Id, E, What) ->
    case get(<<"MqttExtra">>, E) of
        undefined -> {ok, ok};
        Text ->
            Good = fun(T) -> case binary:split(T, <<"=">>) of
                                 [N, V] -> is_name(N) andalso V =/= <<>>;
                                 _ -> false
                             end
                   end,
            case lists:all(Good, tokens(Text)) of
                true -> {ok, ok};
                false -> {error, [problem(Id, E, What, <<"MqttExtra">>,
                                          <<"expected Name=Value tokens">>)]}
            end
    end.

%% MqttNumeric: the values (names of MqttValue) that must be numbers, as
%% Home Assistant wants of a sensor with a unit, a state class or a
%% numeric device class (docs/mqtt.md section 3.3).
numeric(Id, E, What) ->
    case get(<<"MqttNumeric">>, E) of
        undefined -> {ok, []};
        Text ->
            Read = case get(<<"MqttValue">>, E) of
                       undefined -> [];
                       V -> [P || [P, _] <- [binary:split(T, <<"=">>) || T <- tokens(V)]]
                   end,
            case {tokens(Text), [T || T <- tokens(Text), not lists:member(T, Read)]} of
                {[_ | _] = Names, []} -> {ok, lists:usort(Names)};
                {_, Bad} -> {error, [problem(Id, E, What, <<"MqttNumeric">>,
                                             not_token(<<"expected names of values MqttValue reads">>,
                                                       Bad))]}
            end
    end.

%% `Expected', and the first bad token quoted (at most 64 characters).
not_token(Expected, []) ->
    Expected;
not_token(Expected, [Bad | _]) ->
    Quoted = case string:length(Bad) > 64 of
                 true -> [string:slice(Bad, 0, 64), "..."];
                 false -> Bad
             end,
    unicode:characters_to_binary([Expected, ", not '", Quoted, "'"]).

%% MqttArgCheck: `Param', `Param=Min..Max' or `Param=a|b|c' tokens.
checks(Id, E) ->
    case get(<<"MqttArgCheck">>, E) of
        undefined -> {ok, []};
        Text ->
            Parsed = [{T, check_token(T)} || T <- tokens(Text)],
            case [T || {T, error} <- Parsed] of
                [] -> {ok, [C || {_, C} <- Parsed]};
                Bad -> {error, [problem(Id, E, "Service", <<"MqttArgCheck">>,
                                        not_token(<<"expected Param, Param=Min..Max or "
                                                    "Param=a|b|c tokens">>, Bad))]}
            end
    end.

check_token(T) ->
    case binary:split(T, <<"=">>) of
        [P] -> name_check(P, present);
        [P, Spec] ->
            case binary:split(Spec, <<"..">>) of
                [Lo, Hi] ->
                    case {number(Lo), number(Hi)} of
                        {{ok, L}, {ok, H}} when L =< H -> name_check(P, {range, L, H});
                        _ -> error
                    end;
                [_] ->
                    case [unescape(V) || V <- binary:split(Spec, <<"|">>, [global]), V =/= <<>>] of
                        [] -> error;
                        Vs -> name_check(P, {one_of, Vs})
                    end
            end
    end.

%% A value of an MqttArgCheck list: `%XX' is the byte XX (so a value may
%% hold a space, `|' or `%'); a `%' not followed by two hex digits is
%% itself.
unescape(V) -> unescape(V, <<>>).

unescape(<<"%", H1, H2, Rest/binary>>, Acc) when ?IS_HEX(H1), ?IS_HEX(H2) ->
    unescape(Rest, <<Acc/binary, (binary_to_integer(<<H1, H2>>, 16))>>);
unescape(<<C, Rest/binary>>, Acc) ->
    unescape(Rest, <<Acc/binary, C>>);
unescape(<<>>, Acc) ->
    Acc.

name_check(P, Check) ->
    case is_name(P) of
        true -> {P, Check};
        false -> error
    end.

number(B) ->
    case evatar_json:decode(B) of
        {ok, N} when is_number(N) -> {ok, N};
        _ -> error
    end.

%% MqttCode: pbkdf2-sha256:Iterations:SaltHex:HashHex.
code(Id, E) ->
    case get(<<"MqttCode">>, E) of
        undefined -> {ok, undefined};
        Text ->
            Bad = {error, [problem(Id, E, "Service", <<"MqttCode">>,
                                   <<"expected pbkdf2-sha256:Iterations:SaltHex:HashHex">>)]},
            case binary:split(Text, <<":">>, [global]) of
                [<<"pbkdf2-sha256">>, I, Salt, Hash] ->
                    try {binary_to_integer(I), binary:decode_hex(Salt), binary:decode_hex(Hash)} of
                        {N, S, H} when N > 0, N =< 1000000, byte_size(H) > 0 ->
                            {ok, {pbkdf2_sha256, N, S, H}};
                        _ -> Bad
                    catch error:badarg -> Bad
                    end;
                _ -> Bad
            end
    end.

room(Entries) ->
    case [V || #{parameters := Ps} <- Entries, {<<"Room">>, V} <- Ps] of
        [R | _] -> R;
        [] -> undefined
    end.

feedback_body(Consumes) ->
    case [{C, T} || #{category := C, type := T} <- Consumes,
                    keyword(T) =:= <<"actionfeedback">>] of
        [Body | _] -> Body;
        [] -> {<<"ACTUATOR">>, <<"ACTION FEEDBACK">>}
    end.

read_body([#{category := C, type := T} | _]) -> {C, T};
read_body([]) -> {<<"SENSOR">>, <<"Reading">>}.

%% ---------------------------------------------------------------------------
%% Entries
%% ---------------------------------------------------------------------------

stream(Id, E, Inherited) ->
    What = "Consumes",
    Topic = topic(Id, E, What, <<"MqttStateTopic">>, get(<<"MqttStateTopic">>, E, Inherited),
                  <<"a stream needs a state topic (MqttStateTopic on this or another entry)">>),
    Mapping = mapping(Id, E, What),
    Context = case get(<<"MqttContext">>, E) of
                  undefined -> {ok, sensor_data};
                  V -> case keyword(V) of
                           <<"sensordata">> -> {ok, sensor_data};
                           <<"event">> -> {ok, event};
                           _ -> {error, [problem(Id, E, What, <<"MqttContext">>,
                                                 <<"must be SensorData or Event">>)]}
                       end
              end,
    OnChange = case get(<<"MqttOnChange">>, E) of
                   undefined -> {ok, false};
                   <<"yes">> -> {ok, true};
                   <<"no">> -> {ok, false};
                   _ -> {error, [problem(Id, E, What, <<"MqttOnChange">>, <<"must be yes or no">>)]}
               end,
    case collect([Topic, Mapping, Context, OnChange, extra(Id, E, What), numeric(Id, E, What)]) of
        {ok, [T, M, Ctx, Change, ok, Numeric]} ->
            #{category := Cat, type := Type} = E,
            {ok, #{category => Cat, type => Type, static => static(E), topic => T,
                   context => Ctx, on_change => Change, numeric => Numeric, mapping => M}};
        Error ->
            Error
    end.

service(Id, #{category := Cat, type := Type} = E, Inherited, HasStreams) ->
    Base = #{category => Cat, type => Type, static => static(E)},
    Orphans = [N || {N, _} <- maps:get(parameters, E), lists:member(N, ?COMMAND_ONLY)],
    case get(<<"MqttCommand">>, E) of
        undefined when Orphans =/= [] ->
            %% A misspelt MqttCommand (reported as unknown) leaves its
            %% parameters: they are checked all the same, so every mistake
            %% of the entry is named at once.
            {error, [problem(Id, E, "Service", hd(Orphans),
                             <<"given without MqttCommand (a service without one is a read "
                               "service, which takes no command parameters)">>)]
                    ++ case command_service(Id, E, Inherited, Base, <<"raw:">>) of
                           {error, Ps} -> Ps;
                           {ok, _} -> []
                       end};
        undefined when HasStreams -> {ok, Base#{kind => read}};
        undefined -> {ok, Base#{kind => unsupported}};
        <<"light:", _/binary>> = Command -> light_service(Id, E, Base, Command);
        Command -> command_service(Id, E, Inherited, Base, Command)
    end.

%% `MqttCommand' `light:on' or `light:off' with the light's HA config in
%% `MqttLight' (docs/mqtt.md section 2.7): mqtt_avatar_light makes the
%% publishes and reads the states, on the topics of that config.
light_service(Id, E, Base, Command) ->
    What = "Service",
    OnOff = case Command of
                <<"light:on">> -> {ok, on};
                <<"light:off">> -> {ok, off};
                _ -> {error, [problem(Id, E, What, <<"MqttCommand">>, <<"must be light:on or light:off">>)]}
            end,
    Light = case get(<<"MqttLight">>, E) of
                undefined ->
                    {error, [problem(Id, E, What, <<"MqttLight">>,
                                     <<"a light:on or light:off command needs the light's config">>)]};
                Text ->
                    case evatar_json:decode(Text) of
                        {ok, Json} ->
                            case mqtt_avatar_light:config(Json) of
                                {ok, L} -> {ok, L};
                                {error, M} -> {error, [problem(Id, E, What, <<"MqttLight">>, M)]}
                            end;
                        {error, R} ->
                            {error, [problem(Id, E, What, <<"MqttLight">>, evatar_json:format_error(R))]}
                    end
            end,
    case collect([OnOff, Light, mapping(Id, E, What)]) of
        {ok, [O, L1, Mapping]} ->
            {ok, Base#{kind => command, command => {light, O}, light => L1,
                       command_topic => mqtt_avatar_light:command_topic(L1), args => [],
                       state_topic => undefined,
                       expect => case mqtt_avatar_light:optimistic(L1) of
                                     true -> none;
                                     false -> light
                                 end,
                       progress => undefined, mapping => Mapping}};
        Error ->
            Error
    end.

command_service(Id, E, Inherited, Base, Command) ->
    What = "Service",
    StateTopic = case get(<<"MqttStateTopic">>, E, Inherited) of
                     undefined -> {ok, undefined};
                     ST -> topic(Id, E, What, <<"MqttStateTopic">>, ST, <<>>)
                 end,
    Results = [topic(Id, E, What, <<"MqttCommandTopic">>, get(<<"MqttCommandTopic">>, E, Inherited),
                     <<"a command needs MqttCommandTopic (on this or another entry)">>),
               command(Id, E, Command),
               args(Id, E),
               StateTopic,
               optional_match(Id, E, <<"MqttProgress">>),
               mapping(Id, E, What),
               extra(Id, E, What),
               checks(Id, E),
               code(Id, E),
               command_template(Id, E),
               %% (its own mistakes too when the state topic has one)
               expect(Id, E, get(<<"MqttStateTopic">>, E, Inherited))],
    case collect(Results) of
        {ok, [CT, Cmd, Args, ST1, Progress, Mapping, ok, Checks, Code, CmdTpl, Expect]} ->
            {ok, Base#{kind => command, command_topic => CT, command => Cmd, args => Args,
                       state_topic => ST1, expect => Expect, progress => Progress,
                       mapping => Mapping, checks => Checks, code => Code,
                       command_template => CmdTpl}};
        Error ->
            Error
    end.

command(_Id, _E, <<"raw:", Text/binary>>) ->
    {ok, {raw, Text}};
command(Id, E, <<"json:", Text/binary>> = _V) ->
    case evatar_json:decode(Text) of
        {ok, J} -> {ok, {json, J}};
        {error, R} -> {error, [problem(Id, E, "Service", <<"MqttCommand">>,
                                       evatar_json:format_error(R))]}
    end;
command(Id, E, _) ->
    {error, [problem(Id, E, "Service", <<"MqttCommand">>,
                     <<"must start with raw: or json:">>)]}.

args(Id, E) ->
    case get(<<"MqttCommandArgs">>, E) of
        undefined ->
            {ok, []};
        V ->
            Parsed = [arg(T) || T <- tokens(V)],
            case lists:member(error, Parsed) of
                false -> {ok, Parsed};
                true -> {error, [problem(Id, E, "Service", <<"MqttCommandArgs">>,
                                         <<"expected Param or Param=field.path tokens">>)]}
            end
    end.

arg(Token) ->
    case binary:split(Token, <<"=">>) of
        [Param] -> arg(Param, Param);
        [Param, Field] -> arg(Param, Field)
    end.

arg(Param, Field) ->
    case {is_name(Param), path(Field)} of
        {true, {ok, {json, [_ | _] = P}}} -> {Param, P};
        _ -> error
    end.

%% MqttExpect; by default `any' with a state topic, else `none'.
expect(Id, E, StateTopic) ->
    case get(<<"MqttExpect">>, E) of
        undefined when StateTopic =:= undefined -> {ok, none};
        undefined -> {ok, any};
        <<"none">> -> {ok, none};
        <<"any">> when StateTopic =/= undefined -> {ok, any};
        V when StateTopic =/= undefined ->
            case match(V) of
                {ok, M} -> {ok, M};
                error -> {error, [problem(Id, E, "Service", <<"MqttExpect">>,
                                          <<"must be none, any, raw:TEXT, json:PATH=TEXT or template:TEXT">>)]}
            end;
        _ ->
            {error, [problem(Id, E, "Service", <<"MqttExpect">>,
                             <<"waiting for a state echo needs MqttStateTopic">>)]}
    end.

optional_match(Id, E, Name) ->
    case get(Name, E) of
        undefined -> {ok, undefined};
        V -> case match(V) of
                 {ok, M} -> {ok, M};
                 error -> {error, [problem(Id, E, "Service", Name,
                                           <<"must be raw:TEXT, json:PATH=TEXT or template:TEXT">>)]}
             end
    end.

match(<<"raw:", Text/binary>>) ->
    {ok, {raw, Text}};
match(<<"template:", Text/binary>>) ->
    {ok, {template, Text}};
match(<<"json:", Rest/binary>>) ->
    case binary:split(Rest, <<"=">>) of
        [Path, Value] ->
            case path(Path) of
                {ok, {json, P}} -> {ok, {json, P, Value}};
                error -> error
            end;
        _ -> error
    end;
match(_) ->
    error.

mapping(Id, E, What) ->
    Values = case get(<<"MqttValue">>, E) of
                 undefined -> {ok, []};
                 V -> values(Id, E, What, V)
             end,
    Attributes = case get(<<"MqttAttributes">>, E) of
                     undefined -> {ok, false};
                     <<"all">> -> {ok, true};
                     <<"none">> -> {ok, false};
                     _ -> {error, [problem(Id, E, What, <<"MqttAttributes">>,
                                           <<"must be all or none">>)]}
                 end,
    Map = case get(<<"MqttMap">>, E) of
              undefined -> {ok, []};
              M -> value_map(Id, E, What, M)
          end,
    Template = case {get(<<"MqttValueTemplate">>, E), Values} of
                   {undefined, {ok, Vs0}} ->
                       case lists:keymember(template, 2, Vs0) of
                           true -> {error, [problem(Id, E, What, <<"MqttValue">>,
                                                    <<"Param=template needs MqttValueTemplate">>)]};
                           false -> {ok, #{}}
                       end;
                   {undefined, _} -> {ok, #{}};
                   {T, _} -> template(Id, E, What, <<"MqttValueTemplate">>, T)
               end,
    Scale = case get(<<"MqttScale">>, E) of
                undefined -> {ok, []};
                Sc -> scale(Id, E, What, Sc)
            end,
    case collect([Values, Attributes, Map, Template, Scale]) of
        {ok, [Vs, A, Mp, Tpl, []]} -> {ok, Tpl#{values => Vs, attributes => A, map => Mp}};
        {ok, [Vs, A, Mp, Tpl, Scs]} -> {ok, Tpl#{values => Vs, attributes => A, map => Mp,
                                                 scale => Scs}};
        Error -> Error
    end.

%% MqttScale: `Param=Lo..Hi' tokens, integers Lo =< Hi.
scale(Id, E, What, Text) ->
    token_list(Id, E, What, <<"MqttScale">>, Text, fun scale_token/1,
               <<"expected Param=Lo..Hi tokens (integers, Lo =< Hi)">>).

%% One or more space-separated tokens, each read by `Parse' (`error' when
%% it cannot), or the problem `Message' of parameter `Name'.
token_list(Id, E, What, Name, Text, Parse, Message) ->
    Parsed = [{T, Parse(T)} || T <- tokens(Text)],
    case [T || {T, error} <- Parsed] of
        [] when Parsed =/= [] -> {ok, [P || {_, P} <- Parsed]};
        Bad -> {error, [problem(Id, E, What, Name, not_token(Message, Bad))]}
    end.

scale_token(T) ->
    case binary:split(T, <<"=">>) of
        [P, Spec] ->
            case [number(X) || X <- binary:split(Spec, <<"..">>)] of
                [{ok, L}, {ok, H}] when is_integer(L), is_integer(H), L =< H, H - L < 1000000 ->
                    case is_name(P) of
                        true -> {P, L, H};
                        false -> error
                    end;
                _ -> error
            end;
        _ -> error
    end.

template(Id, E, What, Name, Text) ->
    case mqtt_avatar_template:parse(Text) of
        {ok, T} -> {ok, #{template => T, template_text => Text}};
        {error, M} -> {error, [problem(Id, E, What, Name, M)]}
    end.

command_template(Id, E) ->
    case get(<<"MqttCommandTemplate">>, E) of
        undefined -> {ok, undefined};
        Text -> case template(Id, E, "Service", <<"MqttCommandTemplate">>, Text) of
                    {ok, #{template := T}} -> {ok, T};
                    Error -> Error
                end
    end.

values(Id, E, What, Text) ->
    token_list(Id, E, What, <<"MqttValue">>, Text, fun value_token/1,
               <<"expected Param=raw, Param=json:field.path or Param=template tokens">>).

value_token(Token) ->
    case binary:split(Token, <<"=">>) of
        [Param, Source] ->
            case {is_name(Param), parse_source(Source)} of
                {true, {ok, S}} -> {Param, S};
                _ -> error
            end;
        _ -> error
    end.

value_map(Id, E, What, Text) ->
    Pairs = [binary:split(T, <<"=">>) || T <- tokens(Text)],
    case lists:all(fun(P) -> length(P) =:= 2 end, Pairs) of
        true -> {ok, [{string:casefold(F), To} || [F, To] <- Pairs]};
        false -> {error, [problem(Id, E, What, <<"MqttMap">>, <<"expected from=to tokens">>)]}
    end.

availability(Id, Inherited) ->
    E = #{category => <<"(component)">>, type => <<>>, parameters => []},
    Entries = [availability_entry(Id, E, Suffix, Inherited)
               || Suffix <- [<<>> | [integer_to_binary(I) || I <- lists:seq(2, ?MAX_AVAILABILITY)]],
                  maps:is_key(<<"MqttAvailabilityTopic", Suffix/binary>>, Inherited)],
    Mode = case maps:get(<<"MqttAvailabilityMode">>, Inherited, <<"latest">>) of
               <<"latest">> -> {ok, latest};
               <<"all">> -> {ok, all};
               <<"any">> -> {ok, any};
               _ -> {error, [problem(Id, E, "Component", <<"MqttAvailabilityMode">>,
                                     <<"must be all, any or latest">>)]}
           end,
    case collect([Mode | Entries]) of
        {ok, [_]} -> {ok, undefined};
        {ok, [M | Es]} -> {ok, #{mode => M, entries => Es}};
        Error -> Error
    end.

availability_entry(Id, E, Suffix, Inherited) ->
    Get = fun(Name, Default) -> maps:get(<<Name/binary, Suffix/binary>>, Inherited, Default) end,
    Topic = Get(<<"MqttAvailabilityTopic">>, undefined),
    case {valid_topic(Topic), availability_source(Get(<<"MqttAvailabilityValue">>, <<"raw">>))} of
        {true, {ok, S}} ->
            {ok, #{topic => Topic,
                   online => Get(<<"MqttPayloadAvailable">>, <<"online">>),
                   offline => Get(<<"MqttPayloadNotAvailable">>, <<"offline">>),
                   value => S}};
        {false, _} ->
            {error, [problem(Id, E, "Component", <<"MqttAvailabilityTopic", Suffix/binary>>,
                             <<"a topic must be non-empty, without + or #">>)]};
        {true, error} ->
            {error, [problem(Id, E, "Component", <<"MqttAvailabilityValue", Suffix/binary>>,
                             <<"must be raw, json:field.path or template:TEMPLATE">>)]};
        {true, {error, Message}} ->
            {error, [problem(Id, E, "Component", <<"MqttAvailabilityValue", Suffix/binary>>,
                             Message)]}
    end.

availability_source(<<"template:", Text/binary>>) ->
    case mqtt_avatar_template:parse(Text) of
        {ok, _} -> {ok, {template, Text}};
        {error, _} = Error -> Error
    end;
availability_source(Text) ->
    case parse_source(Text) of
        {ok, template} -> error;             % MqttValueTemplate is for values
        Parsed -> Parsed
    end.

topic(Id, E, What, Name, undefined, Missing) ->
    {error, [problem(Id, E, What, Name, Missing)]};
topic(Id, E, What, Name, Topic, _Missing) ->
    case valid_topic(Topic) of
        true -> {ok, Topic};
        false -> {error, [problem(Id, E, What, Name,
                                  <<"a topic must be non-empty, without + or #">>)]}
    end.

valid_topic(<<>>) -> false;
valid_topic(T) -> binary:match(T, [<<"+">>, <<"#">>, <<0>>]) =:= nomatch.

topics(Components) ->
    Ts = lists:append([[T || #{topic := T} <- Streams]
                       ++ [T || #{state_topic := T} <- Services, T =/= undefined]
                       ++ [T || #{light := L} <- Services, T <- mqtt_avatar_light:state_topics(L)]
                       ++ [T || #{entries := Es} <- [A || A <- [Avail], A =/= undefined],
                                #{topic := T} <- Es]
                       || #{streams := Streams, services := Services, availability := Avail}
                              <- Components]),
    lists:usort(Ts).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

path(<<>>) ->
    {ok, {json, []}};
path(Text) ->
    Segments = binary:split(Text, <<".">>, [global]),
    case lists:member(<<>>, Segments) of
        true -> error;
        false -> {ok, {json, Segments}}
    end.

tokens(Text) ->
    string:lexemes(Text, " \t\n\r").

%% @doc A name BIL can write as an element: an ASCII letter or `_' first,
%% then letters, digits, `_', `-' or `.'.
-spec is_name(binary()) -> boolean().
is_name(<<C, Rest/binary>>) when (C >= $a andalso C =< $z); (C >= $A andalso C =< $Z); C =:= $_ ->
    lists:all(fun(X) -> is_alnum(X) orelse X =:= $_ orelse X =:= $- orelse X =:= $. end,
              binary_to_list(Rest)) andalso binary:match(Rest, <<":">>) =:= nomatch;
is_name(_) ->
    false.

is_alnum(C) when C >= $a, C =< $z -> true;
is_alnum(C) when C >= $A, C =< $Z -> true;
is_alnum(C) when C >= $0, C =< $9 -> true;
is_alnum(C) when C > 127 -> unicode_alnum(C);
is_alnum(_) -> false.

%% Outside ASCII: letters are what has a case or is not punctuation or space.
unicode_alnum(C) ->
    not lists:member(C, [16#A0, 16#2000, 16#2001, 16#2002, 16#2003, 16#3000, 16#A7, 16#B7,
                         16#2013, 16#2014, 16#2018, 16#2019, 16#201C, 16#201D, 16#2026]).

collect(Results) ->
    case [P || {error, Ps} <- Results, P <- Ps] of
        [] -> {ok, [V || {ok, V} <- Results]};
        Problems -> {error, Problems}
    end.

problem(Id, #{category := C, type := T}, What, Name, Message) ->
    #{component => Id, entry => iolist_to_binary([What, " ", C, "/", T]),
      parameter => Name, message => Message}.
