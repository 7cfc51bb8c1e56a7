%% @doc Property tests of the MQTT 3.1.1 / 5.0 codec: round trips of every
%% packet type, malformed input gives errors and never an exception, and a
%% chunked stream decodes like the whole.
-module(mqtt_client_codec_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").

-export([all/0, groups/0, suite/0]).
-export([round_trip_v311/1, round_trip_v5/1, varint/1, random_bytes/1,
         mutated_packets/1, truncated_packets/1, chunked_stream/1, max_packet_size/1,
         utf8_rules/1, topic_rules/1, known_bytes/1, bad_fixed_headers/1,
         v5_property_errors/1]).

-define(N, list_to_integer(os:getenv("MQTT_PROPER_N", "300"))).

suite() -> [{timetrap, {minutes, 2}}].

all() -> [{group, properties}, {group, examples}].

groups() ->
    [{properties, [], [round_trip_v311, round_trip_v5, varint, random_bytes,
                       mutated_packets, truncated_packets, chunked_stream]},
     {examples, [], [max_packet_size, utf8_rules, topic_rules, known_bytes,
                     bad_fixed_headers, v5_property_errors]}].

check(Prop) ->
    ok = evatar_test_proper:check(Prop, ?N).

%%--------------------------------------------------------------------
%% Properties
%%--------------------------------------------------------------------

%% @doc Every 3.1.1 packet type decodes to what was encoded.
round_trip_v311(_Config) ->
    check(prop_round_trip(v311)).

%% @doc Every 5.0 packet type, with properties, decodes to what was encoded.
round_trip_v5(_Config) ->
    check(prop_round_trip(v5)).

prop_round_trip(V) ->
    ?FORALL(P, packet(V),
            begin
                Bin = iolist_to_binary(mqtt_client_codec:encode(P, V)),
                {ok, [P1], _} = mqtt_client_codec:parse(Bin, parser(V)),
                ?WHENFAIL(ct:pal("~p~n~p~n~p", [P, Bin, P1]), normalize(P) =:= P1)
            end).

%% @doc Variable byte integers round trip; 5-byte and non-minimal forms are
%% rejected.
varint(_Config) ->
    check(?FORALL(N, oneof([range(0, 127), range(128, 16383), range(16384, 2097151),
                            range(2097152, 268435455)]),
                  begin
                      B = mqtt_client_codec:encode_varint(N),
                      {ok, N, <<>>} = mqtt_client_codec:decode_varint(B),
                      more = mqtt_client_codec:decode_varint(binary:part(B, 0, byte_size(B) - 1)),
                      true
                  end)),
    {error, bad_varint} = mqtt_client_codec:decode_varint(<<255, 255, 255, 255, 1>>),
    {error, bad_varint} = mqtt_client_codec:decode_varint(<<128, 0>>),
    {ok, 268435455, <<>>} = mqtt_client_codec:decode_varint(<<255, 255, 255, 127>>).

%% @doc Random bytes never raise: the parser answers packets or an error.
random_bytes(_Config) ->
    check(?FORALL({V, Bin}, {version(), binary()}, no_crash(V, Bin))),
    %% Random bodies behind a plausible fixed header reach the body decoders.
    check(?FORALL({V, Type, Flags, Body}, {version(), range(0, 15), range(0, 15), binary()},
                  no_crash(V, <<Type:4, Flags:4, (mqtt_client_codec:encode_varint(
                                                     byte_size(Body)))/binary, Body/binary>>))).

%% @doc Valid packets with bytes changed, inserted or removed never raise.
mutated_packets(_Config) ->
    check(?FORALL({V, P, Muts}, ?LET(V, version(), {V, packet(V), list(mutation())}),
                  begin
                      Bin = iolist_to_binary(mqtt_client_codec:encode(P, V)),
                      no_crash(V, mutate(Bin, Muts))
                  end)).

%% @doc A packet cut short yields nothing yet (and `more'), never an error.
truncated_packets(_Config) ->
    check(?FORALL({V, P, Cut}, ?LET(V, version(), {V, packet(V), pos_integer()}),
                  begin
                      Bin = iolist_to_binary(mqtt_client_codec:encode(P, V)),
                      Short = binary:part(Bin, 0, max(0, byte_size(Bin) - Cut)),
                      {ok, [], _} = mqtt_client_codec:parse(Short, parser(V)),
                      more =:= mqtt_client_codec:decode(Short, V)
                  end)).

%% @doc Packets fed in arbitrary chunks decode to the same list as the
%% whole stream at once, and to the packets encoded.
chunked_stream(_Config) ->
    check(?FORALL({V, Ps, Cuts}, ?LET(V, version(), {V, non_empty(list(packet(V))),
                                                     list(pos_integer())}),
                  begin
                      Bin = iolist_to_binary([mqtt_client_codec:encode(P, V) || P <- Ps]),
                      {ok, Whole, _} = mqtt_client_codec:parse(Bin, parser(V)),
                      Chunks = split(Bin, Cuts),
                      {Got, Parser} = lists:foldl(
                                        fun(C, {Acc, Pr}) ->
                                                {ok, New, Pr1} = mqtt_client_codec:parse(C, Pr),
                                                {Acc ++ New, Pr1}
                                        end, {[], parser(V)}, Chunks),
                      %% Nothing is left over in the parser.
                      {ok, [], _} = mqtt_client_codec:parse(<<>>, Parser),
                      Whole =:= Got andalso Got =:= [normalize(P) || P <- Ps]
                  end)).

no_crash(V, Bin) ->
    R1 = mqtt_client_codec:parse(Bin, mqtt_client_codec:parser(#{version => V,
                                                               max_packet_size => 4096})),
    R2 = mqtt_client_codec:decode(Bin, V),
    ok1(R1) andalso ok2(R2).

ok1({ok, L, _}) when is_list(L) -> true;
ok1({error, _}) -> true.

ok2({ok, #{type := _}, B}) when is_binary(B) -> true;
ok2(more) -> true;
ok2({error, _}) -> true.

mutation() ->
    oneof([{flip, nat(), range(1, 255)}, {insert, nat(), byte()}, {delete, nat()}]).

mutate(Bin, []) ->
    Bin;
mutate(<<>>, [_ | Rest]) ->
    mutate(<<>>, Rest);
mutate(Bin, [{flip, Pos, X} | Rest]) ->
    P = Pos rem byte_size(Bin),
    <<A:P/binary, B, C/binary>> = Bin,
    mutate(<<A/binary, (B bxor X), C/binary>>, Rest);
mutate(Bin, [{insert, Pos, Byte} | Rest]) ->
    P = Pos rem (byte_size(Bin) + 1),
    <<A:P/binary, C/binary>> = Bin,
    mutate(<<A/binary, Byte, C/binary>>, Rest);
mutate(Bin, [{delete, Pos} | Rest]) ->
    P = Pos rem byte_size(Bin),
    <<A:P/binary, _, C/binary>> = Bin,
    mutate(<<A/binary, C/binary>>, Rest).

split(Bin, []) ->
    [Bin];
split(Bin, [N | Rest]) when N < byte_size(Bin) ->
    <<A:N/binary, B/binary>> = Bin,
    [A | split(B, Rest)];
split(Bin, _) ->
    [Bin].

parser(V) ->
    mqtt_client_codec:parser(#{version => V}).

%% The decoder returns payloads as binaries.
normalize(#{type := publish, payload := P} = M) -> M#{payload := iolist_to_binary(P)};
normalize(M) -> M.

%%--------------------------------------------------------------------
%% Generators
%%--------------------------------------------------------------------

version() -> oneof([v311, v5]).

packet(V) ->
    oneof([connect(V), connack(V), publish(V), ack(V), subscribe(V), suback(V),
           unsubscribe(V), unsuback(V), return(#{type => pingreq}),
           return(#{type => pingresp}), disconnect(V)]
          ++ case V of v5 -> [auth()]; v311 -> [] end).

connect(V) ->
    ?LET({Clean, KA, Id, Props, Will, User, Pass},
         {boolean(), range(0, 65535), str(), props(V), oneof([none, will(V)]),
          oneof([none, str()]), oneof([none, binary()])},
         begin
             P0 = #{type => connect, proto => V, clean_start => Clean, keepalive => KA,
                    client_id => Id, properties => Props},
             P1 = case Will of none -> P0; _ -> P0#{will => Will} end,
             P2 = case User of none -> P1; _ -> P1#{username => User} end,
             case {Pass, User, V} of
                 {none, _, _} -> P2;
                 {_, none, v311} -> P2;  % 3.1.1: no password without a user name
                 _ -> P2#{password => Pass}
             end
         end).

will(V) ->
    ?LET({T, P, Q, R, Props}, {topic(), binary(), range(0, 2), boolean(), props(V)},
         #{topic => T, payload => P, qos => Q, retain => R, properties => Props}).

connack(v311) ->
    ?LET(RC, range(0, 5),
         ?LET(SP, case RC of 0 -> boolean(); _ -> false end,
              #{type => connack, session_present => SP, reason_code => RC, properties => #{}}));
connack(v5) ->
    ?LET({RC, Props}, {oneof([0, range(16#80, 16#A2)]), props(v5)},
         ?LET(SP, case RC of 0 -> boolean(); _ -> false end,
              #{type => connack, session_present => SP, reason_code => RC,
                properties => Props})).

publish(V) ->
    ?LET({T, P, Q, R, D, Id, Props},
         {topic(), oneof([binary(), list(oneof([binary(), byte()]))]), range(0, 2),
          boolean(), boolean(), packet_id(), props(V)},
         #{type => publish, topic => T, payload => P, qos => Q, retain => R, dup => D,
           packet_id => case Q of 0 -> undefined; _ -> Id end, properties => Props}).

ack(V) ->
    ?LET({Type, Id, RC, Props},
         {oneof([puback, pubrec, pubrel, pubcomp]), packet_id(), reason_code(V), props(V)},
         #{type => Type, packet_id => Id, reason_code => RC, properties => Props}).

subscribe(V) ->
    ?LET({Id, Topics, Props}, {packet_id(), non_empty(list({filter(), sub_opts(V)})), props(V)},
         #{type => subscribe, packet_id => Id, topics => Topics, properties => Props}).

sub_opts(v311) ->
    ?LET(Q, range(0, 2), #{qos => Q, no_local => false, retain_as_published => false,
                           retain_handling => 0});
sub_opts(v5) ->
    ?LET({Q, NL, RAP, RH}, {range(0, 2), boolean(), boolean(), range(0, 2)},
         #{qos => Q, no_local => NL, retain_as_published => RAP, retain_handling => RH}).

suback(v311) ->
    ?LET({Id, RCs}, {packet_id(), list(oneof([0, 1, 2, 16#80]))},
         #{type => suback, packet_id => Id, reason_codes => RCs, properties => #{}});
suback(v5) ->
    ?LET({Id, RCs, Props}, {packet_id(), list(byte()), props(v5)},
         #{type => suback, packet_id => Id, reason_codes => RCs, properties => Props}).

unsubscribe(V) ->
    ?LET({Id, Topics, Props}, {packet_id(), non_empty(list(filter())), props(V)},
         #{type => unsubscribe, packet_id => Id, topics => Topics, properties => Props}).

unsuback(v311) ->
    ?LET(Id, packet_id(),
         #{type => unsuback, packet_id => Id, reason_codes => [], properties => #{}});
unsuback(v5) ->
    ?LET({Id, RCs, Props}, {packet_id(), list(byte()), props(v5)},
         #{type => unsuback, packet_id => Id, reason_codes => RCs, properties => Props}).

disconnect(v311) ->
    return(#{type => disconnect, reason_code => 0, properties => #{}});
disconnect(v5) ->
    ?LET({RC, Props}, {reason_code(v5), props(v5)},
         #{type => disconnect, reason_code => RC, properties => Props}).

auth() ->
    ?LET({RC, Props}, {oneof([0, 16#18, 16#19]), props(v5)},
         #{type => auth, reason_code => RC, properties => Props}).

reason_code(v311) -> return(0);
reason_code(v5) -> oneof([0, 16#10, range(16#80, 16#A2)]).

packet_id() -> range(1, 65535).

props(v311) ->
    return(#{});
props(v5) ->
    ?LET(L, list(prop()),
         lists:foldl(fun({user_property, P}, M) ->
                             maps:update_with(user_property, fun(Ps) -> Ps ++ [P] end, [P], M);
                        ({subscription_identifier, I}, M) ->
                             maps:update_with(subscription_identifier,
                                              fun(Is) -> Is ++ [I] end, [I], M);
                        ({K, Val}, M) -> M#{K => Val}
                     end, #{}, L)).

prop() ->
    oneof([{payload_format_indicator, range(0, 1)},
           {message_expiry_interval, range(0, 16#FFFFFFFF)},
           {content_type, str()},
           {response_topic, topic()},
           {correlation_data, binary()},
           {subscription_identifier, range(1, 268435455)},
           {session_expiry_interval, range(0, 16#FFFFFFFF)},
           {assigned_client_identifier, str()},
           {server_keep_alive, range(0, 65535)},
           {authentication_method, str()},
           {authentication_data, binary()},
           {request_problem_information, range(0, 1)},
           {will_delay_interval, range(0, 16#FFFFFFFF)},
           {request_response_information, range(0, 1)},
           {response_information, str()},
           {server_reference, str()},
           {reason_string, str()},
           {receive_maximum, range(1, 65535)},
           {topic_alias_maximum, range(0, 65535)},
           {topic_alias, range(1, 65535)},
           {maximum_qos, range(0, 1)},
           {retain_available, range(0, 1)},
           {user_property, {str(), str()}},
           {maximum_packet_size, range(1, 16#FFFFFFFF)},
           {wildcard_subscription_available, range(0, 1)},
           {subscription_identifier_available, range(0, 1)},
           {shared_subscription_available, range(0, 1)}]).

%% UTF-8 text without U+0000 or surrogates.
str() ->
    ?LET(Cs, list(char_()), unicode:characters_to_binary(Cs)).

char_() ->
    frequency([{6, range($a, $z)}, {2, range(1, 127)}, {1, range(128, 16#D7FF)},
               {1, range(16#E000, 16#10FFFF)}]).

level() ->
    ?LET(Cs, list(oneof([range($a, $z), range($0, $9), $_, $-, $$, 16#E9, 16#20AC])),
         unicode:characters_to_binary(Cs)).

topic() ->
    ?LET({L, Ls}, {level(), list(level())},
         case iolist_to_binary(lists:join(<<"/">>, [L | Ls])) of
             <<>> -> <<"t">>;
             T -> T
         end).

filter() ->
    ?LET({Ls, Last}, {non_empty(list(oneof([level(), <<"+">>]))),
                      oneof([none, <<"#">>, <<"+">>])},
         case iolist_to_binary(lists:join(<<"/">>, Ls ++ [L || L <- [Last], L =/= none])) of
             <<>> -> <<"#">>;
             F -> F
         end).

%%--------------------------------------------------------------------
%% Examples
%%--------------------------------------------------------------------

%% @doc A packet larger than the parser's limit is refused before its body
%% arrives, and a packet at the limit passes.
max_packet_size(_Config) ->
    P = #{type => publish, topic => <<"t">>, payload => binary:copy(<<"x">>, 100), qos => 0,
          retain => false, dup => false, packet_id => undefined, properties => #{}},
    Bin = iolist_to_binary(mqtt_client_codec:encode(P, v311)),
    Size = byte_size(Bin),
    {ok, [_], _} = mqtt_client_codec:parse(Bin, mqtt_client_codec:parser(
                                                  #{max_packet_size => Size})),
    {error, {packet_too_large, Size, 50}} =
        mqtt_client_codec:parse(binary:part(Bin, 0, 3),
                                mqtt_client_codec:parser(#{max_packet_size => 50})),
    {error, {packet_too_large, _, _}} = mqtt_client_codec:decode(Bin, v311, Size - 1).

%% @doc MQTT strings: U+0000, surrogates, overlong forms and cut sequences
%% are refused wherever a string is decoded.
utf8_rules(_Config) ->
    true = mqtt_client_codec:valid_utf8(<<"héllo €"/utf8>>),
    Bad = [<<0>>, <<"a", 0, "b">>, <<16#ED, 16#A0, 16#80>>, <<16#C0, 16#AF>>,
           <<16#E2, 16#82>>, <<16#FF>>, <<16#F4, 16#90, 16#80, 16#80>>],
    [false = mqtt_client_codec:valid_utf8(B) || B <- Bad],
    [{error, {malformed, publish, bad_utf8}} =
         mqtt_client_codec:decode(<<48, (3 + byte_size(B)), (byte_size(B)):16, B/binary, "x">>,
                                  v311) || B <- Bad],
    %% A bad client id in CONNECT.
    Connect = iolist_to_binary(mqtt_client_codec:encode(
                                 #{type => connect, proto => v311, clean_start => true,
                                   keepalive => 10, client_id => <<"ab">>,
                                   properties => #{}}, v311)),
    BadId = binary:replace(Connect, <<"ab">>, <<0, $b>>),
    {error, {malformed, connect, bad_utf8}} = mqtt_client_codec:decode(BadId, v311).

%% @doc Topic names refuse wildcards; filters allow `+' as a level and `#'
%% as the last level only.
topic_rules(_Config) ->
    ok = mqtt_client_codec:validate_topic_name(<<"a/b/c">>),
    {error, wildcard_in_topic_name} = mqtt_client_codec:validate_topic_name(<<"a/+">>),
    {error, wildcard_in_topic_name} = mqtt_client_codec:validate_topic_name(<<"a/#">>),
    {error, bad_topic_name} = mqtt_client_codec:validate_topic_name(<<>>),
    {error, bad_topic_name} = mqtt_client_codec:validate_topic_name(a),
    [ok = mqtt_client_codec:validate_topic_filter(F)
     || F <- [<<"#">>, <<"+">>, <<"a/+/b">>, <<"a/#">>, <<"+/+">>, <<"/">>, <<"$SYS/#">>]],
    [{error, bad_topic_filter} = mqtt_client_codec:validate_topic_filter(F)
     || F <- [<<"a#">>, <<"a/#/b">>, <<"a+">>, <<"a/b+/c">>, <<"#/">>, <<>>]],
    %% A PUBLISH carrying a wildcard topic is malformed.
    {error, {malformed, publish, wildcard_in_topic_name}} =
        mqtt_client_codec:decode(<<48, 5, 0, 3, "a/#">>, v311),
    %% A SUBSCRIBE with a bad filter is malformed.
    {error, {malformed, subscribe, bad_topic_filter}} =
        mqtt_client_codec:decode(<<130, 7, 0, 1, 0, 2, "a#", 0>>, v311).

%% @doc Byte-exact encodings checked against the specification's layouts.
known_bytes(_Config) ->
    %% CONNECT 3.1.1, clean session, keepalive 60, client id "c".
    <<16, 13, 0, 4, "MQTT", 4, 2, 0, 60, 0, 1, "c">> =
        iolist_to_binary(mqtt_client_codec:encode(
                           #{type => connect, proto => v311, clean_start => true,
                             keepalive => 60, client_id => <<"c">>, properties => #{}}, v311)),
    %% CONNACK 3.1.1 accepted / bad credentials.
    {ok, #{type := connack, reason_code := 0, session_present := true}, <<>>} =
        mqtt_client_codec:decode(<<32, 2, 1, 0>>, v311),
    {ok, #{type := connack, reason_code := 4}, <<>>} =
        mqtt_client_codec:decode(<<32, 2, 0, 4>>, v311),
    %% PUBLISH QoS 1, retain, id 10.
    <<51, 8, 0, 3, "a/b", 0, 10, "x">> =
        iolist_to_binary(mqtt_client_codec:encode_publish(v311, false, 1, true, 10,
                                                          <<"a/b">>, <<"x">>, #{})),
    %% 5.0 PUBLISH QoS 0 carries an empty property block.
    <<48, 6, 0, 1, "t", 0, "hi">> =
        iolist_to_binary(mqtt_client_codec:encode_publish(v5, false, 0, false, undefined,
                                                          <<"t">>, [<<"h">>, $i], #{})),
    %% 5.0 short PUBACK (2 bytes) means success.
    {ok, #{type := puback, packet_id := 7, reason_code := 0, properties := #{}}, <<>>} =
        mqtt_client_codec:decode(<<64, 2, 0, 7>>, v5),
    %% 5.0 CONNACK with session expiry 30 and a user property.
    {ok, #{type := connack, properties := #{session_expiry_interval := 30,
                                            user_property := [{<<"k">>, <<"v">>}]}}, <<>>} =
        mqtt_client_codec:decode(<<32, 15, 0, 0, 12, 16#11, 0, 0, 0, 30,
                                   16#26, 0, 1, "k", 0, 1, "v">>, v5),
    %% SUBACK 3.1.1 with a refusal.
    {ok, #{type := suback, packet_id := 1, reason_codes := [1, 16#80]}, <<>>} =
        mqtt_client_codec:decode(<<144, 4, 0, 1, 1, 16#80>>, v311),
    %% Several packets in one chunk.
    {ok, [#{type := pingresp}, #{type := pingresp}, #{type := puback}], P} =
        mqtt_client_codec:parse(<<208, 0, 208, 0, 64, 2, 0, 1, 208>>,
                                mqtt_client_codec:parser(#{})),
    {ok, [#{type := pingresp}], _} = mqtt_client_codec:parse(<<0>>, P).

%% @doc Reserved packet types, wrong fixed-header flags, QoS 3, packet id 0
%% and trailing bytes are errors.
bad_fixed_headers(_Config) ->
    Cases = [<<0, 0>>,                    % reserved type 0
             <<16#F0, 0>>,                % AUTH in 3.1.1
             <<16#C1, 0>>,                % PINGREQ with flags
             <<16#82, 4, 0, 1, 0, 0>>,    % SUBSCRIBE without topics... and empty filter
             <<16#80, 6, 0, 1, 0, 1, "a", 0>>, % SUBSCRIBE with flags 0
             <<16#36, 5, 0, 1, "t", 0, 1>>,    % PUBLISH QoS 3
             <<16#32, 5, 0, 1, "t", 0, 0>>,    % PUBLISH QoS 1 packet id 0
             <<64, 3, 0, 1, 0>>,               % 3.1.1 PUBACK too long
             <<32, 3, 0, 0, 0>>,               % 3.1.1 CONNACK too long
             <<32, 2, 1, 4>>,                  % session present with an error
             <<208, 1, 0>>,                    % PINGRESP with a body
             <<48, 3, 0, 5, "a">>],            % string longer than the packet
    [{error, _} = mqtt_client_codec:decode(B, v311) || B <- Cases],
    {error, bad_remaining_length} = mqtt_client_codec:decode(<<48, 255, 255, 255, 255, 1>>, v311),
    {error, bad_remaining_length} =
        mqtt_client_codec:parse(<<48, 128, 0>>, mqtt_client_codec:parser(#{})).

%% @doc 5.0: unknown property ids, duplicated single properties, bad
%% boolean values and property lengths past the packet are errors.
v5_property_errors(_Config) ->
    {error, {malformed, connack, {unknown_property, 16#7F}}} =
        mqtt_client_codec:decode(<<32, 5, 0, 0, 2, 16#7F, 0>>, v5),
    {error, {malformed, connack, {duplicate_property, receive_maximum}}} =
        mqtt_client_codec:decode(<<32, 9, 0, 0, 6, 16#21, 0, 1, 16#21, 0, 2>>, v5),
    {error, {malformed, connack, bad_property_value}} =
        mqtt_client_codec:decode(<<32, 5, 0, 0, 2, 16#24, 2>>, v5),
    {error, {malformed, connack, bad_properties_length}} =
        mqtt_client_codec:decode(<<32, 4, 0, 0, 9, 16#24>>, v5),
    %% Repeated user properties keep their order.
    {ok, #{properties := #{user_property := [{<<"a">>, <<"1">>}, {<<"a">>, <<"2">>}]}}, <<>>} =
        mqtt_client_codec:decode(<<32, 17, 0, 0, 14, 16#26, 0, 1, "a", 0, 1, "1",
                                   16#26, 0, 1, "a", 0, 1, "2">>, v5).
