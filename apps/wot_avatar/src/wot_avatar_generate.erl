%% @doc Internal. Turns a Thing (wot_avatar_td:read/2) into the BIL
%% description of its Avatar and the routes that carry the VA's requests
%% to the Thing's forms: one component, actions as ACTUATOR services,
%% properties as `Read' (and, when writable, `Set') services and SENSOR
%% streams (observed, or polled every `poll_ms'), events as SENSOR streams
%% pushed as Event signals and a `Read' service answering the last one. docs/wot.md section 6 lists the rules. Pure.
-module(wot_avatar_generate).

-export([description/2, camel/1, default_poll_ms/0]).

-export_type([opts/0, routes/0, route/0, stream/0, shape/0, field/0]).

%% `component': the ComponentID (default the title, camel-cased);
%% `room': a Room parameter on every entry; `poll_ms': how often a property
%% the Thing cannot be observed on is read for its stream (0: never).
-type opts() :: #{entity_id := binary(), component => binary(), room => binary(),
                  api_name => binary(), poll_ms => non_neg_integer()}.
-type field() :: #{type := binary() | undefined, atom() => term()}.
%% How a JSON value and BIL parameters correspond: `none' (no value),
%% `{value, Field}' (one scalar as parameter `Value'), `{object, Fields}'
%% (a JSON object, each field a parameter: BIL name, JSON name, field).
-type shape() :: none | {value, field()} | {object, [{binary(), binary(), field()}]}.
%% `readevent': answered from the last event of stream `stream' (no form).
-type route() :: #{op := invokeaction | readproperty | writeproperty | readevent, type := binary(),
                   form => wot_avatar_td:form(), stream => binary(), input := shape(), output := shape()}.
-type stream() :: #{type := binary(), context := sensor_data | event, form := wot_avatar_td:form(),
                    mode := longpoll | sse | mqtt | {poll, pos_integer()}, output := shape()}.
%% `services': keyed by the ServiceType's keyword (bil:keyword/1).
-type routes() :: #{component := binary(), services := #{binary() => route()}, streams := [stream()]}.

-define(POLL_MS, 10000).
-define(MAX_TEXT, 256).

%% @doc How often a property that cannot be observed is read, by default.
-spec default_poll_ms() -> pos_integer().
default_poll_ms() -> ?POLL_MS.

%% @doc The Avatar's description, its routes, and the problems of what was
%% left out.
-spec description(wot_avatar_td:thing(), opts()) ->
          {ok, bil:description(), routes(), [wot_avatar_td:problem()]}
        | {error, [wot_avatar_td:problem()]}.
description(#{title := Title} = Thing, #{entity_id := Entity} = Opts) ->
    Component = case maps:get(component, Opts, undefined) of
                    undefined -> first_name(Title, <<"Thing">>);
                    C -> C
                end,
    Room = [{<<"Room">>, R} || R <- [maps:get(room, Opts, undefined)], is_binary(R)],
    Poll = maps:get(poll_ms, Opts, ?POLL_MS),
    Parts = [action(A, Room) || A <- maps:get(actions, Thing)]
        ++ lists:append([property(P, Room, Poll) || P <- maps:get(properties, Thing)])
        ++ [event(E, Room) || E <- maps:get(events, Thing)],
    {Services, Consumes, Routes, Streams, Problems} = assemble(Parts),
    Feedback = [entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>,
                      [{<<"Feedback">>, <<"yes">>}, {<<"Device">>, Component}] ++ Room)
                || #{category := <<"ACTUATOR">>} <- Services],
    D = #{entity_id => Entity, api_name => maps:get(api_name, Opts, <<"WOT AVATAR">>),
          entity_type => avatar, context => <<"WotDescription">>,
          components => [#{id => Component, services => Services,
                           consumes => Consumes ++ lists:sublist(Feedback, 1)}]},
    Checked = case Services ++ Consumes of
                  [] -> nothing_usable;
                  _ -> bil:parse_description(iolist_to_binary(bil:encode_description(D)))
              end,
    case Checked of
        {ok, _} ->
            {ok, D, #{component => Component, services => Routes, streams => Streams}, Problems};
        nothing_usable ->
            {error, Problems ++ [#{what => nothing_usable,
                                   message => <<"no action, property or event of the TD can be driven: "
                                                "the Thing has no Avatar">>}]};
        {error, R} ->
            {error, Problems ++ [#{what => bad_description, message => bil:format_error(R)}]}
    end.

%% One part per affordance: its service and stream (or why it has none).
action(#{name := Name, schema := S, forms := #{invokeaction := Form}}, Room) ->
    with_name(Name, fun(Type) ->
        case {shape(maps:get(<<"input">>, S, #{})), shape(maps:get(<<"output">>, S, #{}))} of
            {{ok, In, P1}, {ok, Out, P2}} ->
                #{name => Name, problems => P1 ++ P2,
                  services => [{entry(<<"ACTUATOR">>, Type, params(In, true) ++ Room),
                                #{op => invokeaction, type => Type, form => Form, input => In,
                                  output => Out}}]};
            {{error, P}, _} -> #{name => Name, problems => [P]};
            {_, {error, P}} -> #{name => Name, problems => [P]}
        end
    end).

property(#{name := Name, schema := S, forms := Forms} = P, Room, Poll) ->
    [with_name(Name, fun(Type) ->
        case shape(S) of
            {error, Pr} ->
                #{name => Name, problems => [Pr]};
            {ok, Shape, Ps} ->
                Read = [{entry(<<"SENSOR">>, <<"Read", Type/binary>>, params(Shape, false) ++ Room),
                         #{op => readproperty, type => <<"Read", Type/binary>>, form => F, input => none,
                           output => Shape}}
                        || #{readproperty := F} <- [Forms]],
                Set = [{entry(<<"ACTUATOR">>, <<"Set", Type/binary>>, params(Shape, true) ++ Room),
                        #{op => writeproperty, type => <<"Set", Type/binary>>, form => F, input => Shape,
                          output => none}}
                       || #{writeproperty := F} <- [Forms], not maps:get(read_only, P, false)],
                Stream = case {maps:get(observable, P, false), Forms} of
                             {true, #{observeproperty := #{subprotocol := Sub} = F}} ->
                                 [stream(Type, sensor_data, F, Sub, Shape, Room)];
                             {_, #{readproperty := F}} when Poll > 0 ->
                                 [stream(Type, sensor_data, F, {poll, Poll}, Shape, Room)];
                             _ ->
                                 []
                         end,
                #{name => Name, problems => Ps, services => Read ++ Set, streams => Stream}
        end
    end)].

event(#{name := Name, schema := S, forms := #{subscribeevent := #{subprotocol := Sub} = F}}, Room) ->
    with_name(Name, fun(Type) ->
        case shape(S) of
            {error, Pr} -> #{name => Name, problems => [Pr]};
            {ok, Shape, Ps} ->
                %% A Read service too: a component needs one, and a VA may ask
                %% for the last event's data.
                #{name => Name, problems => Ps,
                  services => [{entry(<<"SENSOR">>, <<"Read", Type/binary>>, params(Shape, false) ++ Room),
                                #{op => readevent, type => <<"Read", Type/binary>>, stream => Type,
                                  input => none, output => Shape}}],
                  streams => [stream(Type, event, F, Sub, Shape, Room)]}
        end
    end).

stream(Type, Context, Form, Mode, Shape, Room) ->
    {entry(<<"SENSOR">>, Type, Room),
     #{type => Type, context => Context, form => Form, mode => Mode, output => Shape}}.

with_name(Name, Fun) ->
    case camel(Name) of
        {ok, Type} -> Fun(Type);
        {error, Message} -> #{name => Name, problems => [problem(bad_name, Name, Message)]}
    end.

%% Services and streams in TD order, each ServiceType once per component
%% (keywords compared as binding does).
assemble(Parts) ->
    lists:foldl(
      fun(#{name := Name} = Part, {Ss, Cs, Rs, Sts, Ps}) ->
              {Ss1, Rs1, P1} = lists:foldl(
                                 fun({#{type := T} = E, Route}, {S0, R0, Pa}) ->
                                         K = bil:keyword(T),
                                         case maps:is_key(K, R0) of
                                             true -> {S0, R0, Pa ++ [clash(Name, T)]};
                                             false -> {S0 ++ [E], R0#{K => Route}, Pa}
                                         end
                                 end, {Ss, Rs, []}, maps:get(services, Part, [])),
              {Cs1, Sts1, P2} = lists:foldl(
                                  fun({#{type := T} = E, St}, {C0, St0, Pa}) ->
                                          case [x || #{type := T0} <- St0, bil:keyword(T0) =:= bil:keyword(T)] of
                                              [] -> {C0 ++ [E], St0 ++ [St], Pa};
                                              _ -> {C0, St0, Pa ++ [clash(Name, T)]}
                                          end
                                  end, {Cs, Sts, []}, maps:get(streams, Part, [])),
              {Ss1, Cs1, Rs1, Sts1, Ps ++ maps:get(problems, Part) ++ P1 ++ P2}
      end, {[], [], #{}, [], []}, Parts).

clash(Name, Type) ->
    problem(name_clash, Name, <<"its service or stream ", Type/binary, " is another affordance's "
                                "(names are compared as BIL keywords); the first is kept">>).

%% ---------------------------------------------------------------------------
%% Schemas
%% ---------------------------------------------------------------------------

%% The shape of a data schema, with the problems of what it cannot carry
%% (a range or enum value that cannot be BIL text is left out of the
%% description, still checked); `{error, _}' for a schema BIL parameters
%% cannot hold (an array, an object in an object).
shape(S) when map_size(S) =:= 0 -> {ok, none, []};
shape(#{<<"type">> := <<"object">>} = S) ->
    Props = case maps:get(<<"properties">>, S, #{}) of
                #{} = M -> lists:sort(maps:to_list(M));
                _ -> []
            end,
    Fields = [{J, camel(J), field(F)} || {J, F} <- Props],
    case [J || {J, _, {error, _}} <- Fields] ++ [J || {J, {error, _}, _} <- Fields] of
        [] ->
            Names = [B || {_, {ok, B}, _} <- Fields],
            case length(lists:usort([bil:keyword(N) || N <- Names])) =:= length(Names) of
                true -> {ok, {object, [{B, J, F} || {J, {ok, B}, {ok, F}} <- Fields]}, []};
                false -> {error, schema_problem(<<"two of its fields have the same BIL name">>)}
            end;
        [Bad | _] ->
            {error, schema_problem(<<"field ", (wot_text(Bad))/binary, " is not a string, number, "
                                     "integer, boolean or null with a BIL name">>)}
    end;
shape(S) ->
    case field(S) of
        {ok, #{type := undefined}} when not is_map_key(<<"enum">>, S) -> {ok, none, []};
        {ok, F} -> {ok, {value, F}, []};
        {error, Why} -> {error, schema_problem(Why)}
    end.

schema_problem(Message) ->
    #{what => unsupported_schema, message => Message}.

field(#{} = S) ->
    Type = maps:get(<<"type">>, S, undefined),
    case lists:member(Type, [<<"string">>, <<"number">>, <<"integer">>, <<"boolean">>, <<"null">>,
                             undefined]) of
        true ->
            {ok, maps:from_list([{type, Type}]
                                ++ [{K, V} || {J, K} <- [{<<"minimum">>, minimum}, {<<"maximum">>, maximum},
                                                         {<<"multipleOf">>, multiple_of}],
                                              V <- [maps:get(J, S, undefined)], is_number(V)]
                                ++ [{enum, V} || V <- [maps:get(<<"enum">>, S, undefined)], is_list(V)]
                                ++ [{unit, V} || V <- [maps:get(<<"unit">>, S, undefined)], is_binary(V)]
                                ++ [{default, V} || V <- [maps:get(<<"default">>, S, undefined)],
                                                    V =/= undefined])};
        false ->
            {error, <<"a schema of type ", (wot_text(Type))/binary, " cannot be BIL parameters "
                      "(string, number, integer, boolean and null, alone or as an object's fields, can)">>}
    end;
field(_) ->
    {error, <<"a schema that is not an object">>}.

%% The parameters of an entry: each value `yes', then what the schema
%% says of it (`<Name>Type', `Min', `Max', `Step', `Values', `Unit'),
%% for a request's parameters; a reading's are its names.
params(none, _) -> [];
params({value, F}, Caps) -> field_params(<<"Value">>, F, Caps);
params({object, Fs}, Caps) -> lists:append([field_params(B, F, Caps) || {B, _, F} <- Fs]).

field_params(Name, _F, false) -> [{Name, <<"yes">>}];
field_params(Name, F, true) ->
    Caps = [{<<"Type">>, maps:get(type, F)}, {<<"Min">>, maps:get(minimum, F, undefined)},
            {<<"Max">>, maps:get(maximum, F, undefined)}, {<<"Step">>, maps:get(multiple_of, F, undefined)},
            {<<"Values">>, enum_text(maps:get(enum, F, undefined))}, {<<"Unit">>, maps:get(unit, F, undefined)}],
    [{Name, <<"yes">>} | [{<<Name/binary, Suffix/binary>>, T} || {Suffix, V} <- Caps,
                                                                  {ok, T} <- [value_text(V)]]].

enum_text(undefined) -> undefined;
enum_text(Values) ->
    Texts = [value_text(V) || V <- Values],
    case [T || {ok, T} <- Texts, binary:match(T, <<"|">>) =:= nomatch] of
        Ok when length(Ok) =:= length(Values), Ok =/= [] -> iolist_to_binary(lists:join("|", Ok));
        _ -> undefined
    end.

%% Text that BIL can carry: printable, at most ?MAX_TEXT bytes.
value_text(undefined) -> error;
value_text(null) -> error;
value_text(V) when is_binary(V) ->
    Printable = byte_size(V) =< ?MAX_TEXT andalso
        unicode:characters_to_binary(V) =:= V andalso
        lists:all(fun(C) -> C >= 32 andalso C =/= 127 end, binary_to_list(V)),
    case Printable of
        true -> {ok, V};
        false -> error
    end;
value_text(V) when is_number(V); is_boolean(V) -> {ok, evatar_json:to_text(V)};
value_text(_) -> error.

%% ---------------------------------------------------------------------------
%% Names
%% ---------------------------------------------------------------------------

%% @doc A TD name as a BIL name: its ASCII letters and digits, each word
%% capitalised (`set-point' -> `SetPoint'), a leading digit prefixed with
%% `N'; at most 64 bytes.
-spec camel(binary()) -> {ok, binary()} | {error, binary()}.
camel(Name) when is_binary(Name) ->
    Words = re:split(Name, <<"[^A-Za-z0-9]+">>, [{return, binary}, trim]),
    Camel = << <<(upper(W))/binary>> || W <- Words, W =/= <<>> >>,
    case Camel of
        <<>> -> {error, <<"the name has no ASCII letter or digit to make a BIL name of">>};
        <<D, _/binary>> when D >= $0, D =< $9 -> check_length(<<"N", Camel/binary>>);
        _ -> check_length(Camel)
    end.

check_length(B) when byte_size(B) =< 64 -> {ok, B};
check_length(_) -> {error, <<"the name is longer than 64 letters and digits">>}.

upper(<<C, Rest/binary>>) when C >= $a, C =< $z -> <<(C - 32), Rest/binary>>;
upper(W) -> W.

first_name(Title, Default) ->
    case camel(Title) of
        {ok, C} -> C;
        {error, _} -> Default
    end.

entry(Category, Type, Params) ->
    #{category => Category, type => Type, parameters => Params}.

problem(What, Name, Message) ->
    #{what => What, message => Message, affordance => wot_text(Name)}.

wot_text(B) when is_binary(B) ->
    case value_text(B) of
        {ok, T} when byte_size(T) =< 64 -> T;
        _ -> <<"(a name that cannot be shown)">>
    end;
wot_text(undefined) -> <<"(none)">>;
wot_text(_) -> <<"(not a string)">>.
