%% @doc Internal. MQTT 3.1.1 and 5.0 packet codec, pure: packets are maps
%% with a `type' key, encoded to iodata; an incremental parser turns a byte
%% stream (partial packets, several packets per chunk) into packets. Bad bytes
%% give `{error, Reason}', never an exception; wire names stay binaries.
-module(mqtt_client_codec).

-export([encode/2, encode_publish/8, encode_puback/2, encode_pingreq/0]).
-export([parser/1, parse/2, decode/2, decode/3]).
-export([encode_varint/1, decode_varint/1]).
-export([valid_utf8/1, validate_topic_name/1, validate_topic_filter/1]).
-export([reason_name/1]).

-export_type([version/0, qos/0, packet/0, properties/0, parser/0, sub_opts/0,
              reason/0]).

-type version() :: v311 | v5.
-type qos() :: 0 | 1 | 2.
-type packet_id() :: 1..65535.
-type properties() :: #{atom() => term()}.
%% v5 properties, keys from a fixed table (`subscription_identifier' and
%% `user_property' are lists, the rest single values); always `#{}' in 3.1.1.
-type sub_opts() :: #{qos := qos(), no_local := boolean(),
                      retain_as_published := boolean(), retain_handling := 0..2}.
-type will() :: #{topic := binary(), payload := binary(), qos := qos(),
                  retain := boolean(), properties := properties()}.
-type packet() ::
        #{type := connect, proto := version(), clean_start := boolean(),
          keepalive := 0..65535, client_id := binary(), properties := properties(),
          username => binary(), password => binary(), will => will()}
      | #{type := connack, session_present := boolean(), reason_code := byte(),
          properties := properties()}
      | #{type := publish, topic := binary(), payload := iodata(), qos := qos(),
          retain := boolean(), dup := boolean(), packet_id := packet_id() | undefined,
          properties := properties()}
      | #{type := puback | pubrec | pubrel | pubcomp, packet_id := packet_id(),
          reason_code := byte(), properties := properties()}
      | #{type := subscribe, packet_id := packet_id(),
          topics := [{binary(), sub_opts()}], properties := properties()}
      | #{type := suback | unsuback, packet_id := packet_id(),
          reason_codes := [byte()], properties := properties()}
      | #{type := unsubscribe, packet_id := packet_id(), topics := [binary()],
          properties := properties()}
      | #{type := pingreq | pingresp}
      | #{type := disconnect | auth, reason_code := byte(), properties := properties()}.
-type reason() :: term().

-define(MAX_SIZE, 268435460). % 256 MB remaining length + 5 header bytes

-record(parser, {version :: version(),
                 max :: pos_integer(),
                 buf = <<>> :: binary(),
                 need = 0 :: non_neg_integer(),
                 chunks = [] :: [binary()],
                 chunks_size = 0 :: non_neg_integer()}).
-opaque parser() :: #parser{}.

-define(ERR(R), throw({?MODULE, R})).

%%====================================================================
%% Encoding
%%====================================================================

%% @doc Encodes one packet for the given protocol version (a CONNECT uses its
%% own `proto'). Properties are written only for 5.0.
-spec encode(packet(), version()) -> iodata().
encode(#{type := connect} = P, _V) ->
    encode_connect(P);
encode(#{type := connack, session_present := SP, reason_code := RC} = P, V) ->
    packet(2, 0, [<<0:7, (b(SP)):1, RC>>, props(V, P)]);
encode(#{type := publish, topic := T, payload := Pl, qos := Q, retain := R,
         dup := D} = P, V) ->
    encode_publish(V, D, Q, R, maps:get(packet_id, P, undefined), T, Pl,
                   maps:get(properties, P, #{}));
encode(#{type := Ack, packet_id := Id} = P, V)
  when Ack =:= puback; Ack =:= pubrec; Ack =:= pubrel; Ack =:= pubcomp ->
    Flags = case Ack of pubrel -> 2; _ -> 0 end,
    RC = maps:get(reason_code, P, 0),
    Props = maps:get(properties, P, #{}),
    Body = case V of
               v5 when RC =:= 0, map_size(Props) =:= 0 -> <<Id:16>>;
               v5 when map_size(Props) =:= 0 -> <<Id:16, RC>>;
               v5 -> [<<Id:16, RC>>, encode_props(Props)];
               v311 -> <<Id:16>>
           end,
    packet(type_code(Ack), Flags, Body);
encode(#{type := subscribe, packet_id := Id, topics := Topics} = P, V) ->
    packet(8, 2, [<<Id:16>>, props(V, P),
                  [[string(F), sub_opts_byte(V, O)] || {F, O} <- Topics]]);
encode(#{type := suback, packet_id := Id, reason_codes := RCs} = P, V) ->
    packet(9, 0, [<<Id:16>>, props(V, P), list_to_binary(RCs)]);
encode(#{type := unsubscribe, packet_id := Id, topics := Topics} = P, V) ->
    packet(10, 2, [<<Id:16>>, props(V, P), [string(F) || F <- Topics]]);
encode(#{type := unsuback, packet_id := Id} = P, V) ->
    case V of
        v5 -> packet(11, 0, [<<Id:16>>, props(V, P),
                             list_to_binary(maps:get(reason_codes, P, []))]);
        v311 -> packet(11, 0, <<Id:16>>)
    end;
encode(#{type := pingreq}, _V) ->
    encode_pingreq();
encode(#{type := pingresp}, _V) ->
    <<208, 0>>;
encode(#{type := Type} = P, V) when Type =:= disconnect; Type =:= auth ->
    RC = maps:get(reason_code, P, 0),
    Props = maps:get(properties, P, #{}),
    Body = case V of
               v5 when RC =:= 0, map_size(Props) =:= 0, Type =:= disconnect -> <<>>;
               v5 when map_size(Props) =:= 0 -> <<RC>>;
               v5 -> [<<RC>>, encode_props(Props)];
               v311 -> <<>>
           end,
    packet(type_code(Type), 0, Body).

%% @doc Fast path for PUBLISH: the payload is not copied or flattened.
-spec encode_publish(version(), boolean(), qos(), boolean(), packet_id() | undefined,
                     binary(), iodata(), properties()) -> iodata().
encode_publish(V, Dup, QoS, Retain, Id, Topic, Payload, Props) ->
    TL = byte_size(Topic),
    Var0 = case QoS of
               0 -> <<TL:16, Topic/binary>>;
               _ -> <<TL:16, Topic/binary, Id:16>>
           end,
    Var = case V of
              v311 -> Var0;
              v5 when map_size(Props) =:= 0 -> <<Var0/binary, 0>>;
              v5 -> iolist_to_binary([Var0, encode_props(Props)])
          end,
    Len = byte_size(Var) + iolist_size(Payload),
    [<<3:4, (b(Dup)):1, QoS:2, (b(Retain)):1>>, encode_varint(Len), Var, Payload].

%% @doc A PUBACK with reason code 0 (the short form, valid in both versions).
-spec encode_puback(version(), packet_id()) -> binary().
encode_puback(_V, Id) ->
    <<64, 2, Id:16>>.

%% @doc PINGREQ.
-spec encode_pingreq() -> binary().
encode_pingreq() ->
    <<192, 0>>.

encode_connect(#{proto := V, clean_start := Clean, keepalive := KA,
                 client_id := Id} = P) ->
    {Name, Level} = case V of
                        v311 -> {<<"MQTT">>, 4};
                        v5 -> {<<"MQTT">>, 5}
                    end,
    User = maps:get(username, P, undefined),
    Pass = maps:get(password, P, undefined),
    Will = maps:get(will, P, undefined),
    {WillFlag, WQ, WR, WillPart} =
        case Will of
            undefined ->
                {0, 0, 0, []};
            #{topic := WT, payload := WP} ->
                {1, maps:get(qos, Will, 0), b(maps:get(retain, Will, false)),
                 [case V of
                      v5 -> encode_props(maps:get(properties, Will, #{}));
                      v311 -> []
                  end, string(WT), string(WP)]}
        end,
    Flags = <<(present(User)):1, (present(Pass)):1, WR:1, WQ:2, WillFlag:1,
              (b(Clean)):1, 0:1>>,
    packet(1, 0, [string(Name), Level, Flags, <<KA:16>>, props(V, P),
                  string(Id), WillPart, opt_string(User), opt_string(Pass)]).

packet(Type, Flags, Body) ->
    [<<Type:4, Flags:4>>, encode_varint(iolist_size(Body)), Body].

props(v311, _) -> [];
props(v5, P) -> encode_props(maps:get(properties, P, #{})).

sub_opts_byte(v311, #{qos := Q}) ->
    <<0:6, Q:2>>;
sub_opts_byte(v5, O) ->
    <<0:2, (maps:get(retain_handling, O, 0)):2,
      (b(maps:get(retain_as_published, O, false))):1,
      (b(maps:get(no_local, O, false))):1, (maps:get(qos, O)):2>>.

string(S) -> [<<(iolist_size(S)):16>>, S].

opt_string(undefined) -> [];
opt_string(S) -> string(S).

present(undefined) -> 0;
present(_) -> 1.

b(true) -> 1;
b(false) -> 0.

type_code(puback) -> 4;
type_code(pubrec) -> 5;
type_code(pubrel) -> 6;
type_code(pubcomp) -> 7;
type_code(disconnect) -> 14;
type_code(auth) -> 15.

%% @doc MQTT variable byte integer (0..268435455).
-spec encode_varint(0..268435455) -> binary().
encode_varint(N) when N < 128 -> <<N>>;
encode_varint(N) when N < 16384 -> <<1:1, (N band 127):7, (N bsr 7)>>;
encode_varint(N) when N =< 268435455 ->
    <<1:1, (N band 127):7, (encode_varint(N bsr 7))/binary>>.

%% @doc Decodes a variable byte integer at the head of a binary: `more'
%% when it is cut short, an error when longer than 4 bytes or not minimal.
-spec decode_varint(binary()) -> {ok, non_neg_integer(), binary()} | more | {error, reason()}.
decode_varint(<<0:1, A:7, R/binary>>) -> {ok, A, R};
decode_varint(<<1:1, A:7, 0:1, B:7, R/binary>>) -> minimal(B, A + (B bsl 7), R);
decode_varint(<<1:1, A:7, 1:1, B:7, 0:1, C:7, R/binary>>) ->
    minimal(C, A + (B bsl 7) + (C bsl 14), R);
decode_varint(<<1:1, A:7, 1:1, B:7, 1:1, C:7, 0:1, D:7, R/binary>>) ->
    minimal(D, A + (B bsl 7) + (C bsl 14) + (D bsl 21), R);
decode_varint(<<1:1, _:7, 1:1, _:7, 1:1, _:7, 1:1, _:7, _/binary>>) ->
    {error, bad_varint};
decode_varint(_) ->
    more.

minimal(0, _, _) -> {error, bad_varint};
minimal(_, N, R) -> {ok, N, R}.

%%====================================================================
%% Properties (5.0)
%%====================================================================

%% {Id, Name, Type}; Type one of byte, bool (a byte that must be 0 or 1),
%% u16, u32, varint, utf8, bin, pair.
-define(PROPS,
        [{16#01, payload_format_indicator, bool},
         {16#02, message_expiry_interval, u32},
         {16#03, content_type, utf8},
         {16#08, response_topic, utf8},
         {16#09, correlation_data, bin},
         {16#0B, subscription_identifier, varint},
         {16#11, session_expiry_interval, u32},
         {16#12, assigned_client_identifier, utf8},
         {16#13, server_keep_alive, u16},
         {16#15, authentication_method, utf8},
         {16#16, authentication_data, bin},
         {16#17, request_problem_information, bool},
         {16#18, will_delay_interval, u32},
         {16#19, request_response_information, bool},
         {16#1A, response_information, utf8},
         {16#1C, server_reference, utf8},
         {16#1F, reason_string, utf8},
         {16#21, receive_maximum, u16},
         {16#22, topic_alias_maximum, u16},
         {16#23, topic_alias, u16},
         {16#24, maximum_qos, bool},
         {16#25, retain_available, bool},
         {16#26, user_property, pair},
         {16#27, maximum_packet_size, u32},
         {16#28, wildcard_subscription_available, bool},
         {16#29, subscription_identifier_available, bool},
         {16#2A, shared_subscription_available, bool}]).

encode_props(Props) when map_size(Props) =:= 0 ->
    <<0>>;
encode_props(Props) ->
    Body = iolist_to_binary(
             [encode_prop(Name, Value) || {Name, Value} <- lists:sort(maps:to_list(Props))]),
    [encode_varint(byte_size(Body)), Body].

encode_prop(user_property, Pairs) ->
    [[16#26, string(K), string(V)] || {K, V} <- Pairs];
encode_prop(subscription_identifier, Ids) ->
    [[16#0B, encode_varint(I)] || I <- Ids];
encode_prop(Name, Value) ->
    {Id, Type} = prop_by_name(Name),
    [Id, encode_prop_value(Type, Value)].

encode_prop_value(bool, V) -> <<V>>;
encode_prop_value(u16, V) -> <<V:16>>;
encode_prop_value(u32, V) -> <<V:32>>;
encode_prop_value(varint, V) -> encode_varint(V);
encode_prop_value(utf8, V) -> string(V);
encode_prop_value(bin, V) -> string(V).

prop_by_name(Name) ->
    {Id, Name, Type} = lists:keyfind(Name, 2, ?PROPS),
    {Id, Type}.

prop_by_id(Id) ->
    case lists:keyfind(Id, 1, ?PROPS) of
        {Id, Name, Type} -> {Name, Type};
        false -> ?ERR({unknown_property, Id})
    end.

decode_props(v311, Bin) ->
    {#{}, Bin};
decode_props(v5, Bin) ->
    case decode_varint(Bin) of
        {ok, Len, R} when byte_size(R) >= Len ->
            <<Body:Len/binary, Rest/binary>> = R,
            {decode_prop_list(Body, #{}), Rest};
        {ok, _, _} -> ?ERR(bad_properties_length);
        more -> ?ERR(bad_properties_length);
        {error, Reason} -> ?ERR(Reason)
    end.

decode_prop_list(<<>>, Acc) ->
    Acc;
decode_prop_list(Bin, Acc) ->
    {Id, R0} = case decode_varint(Bin) of
                   {ok, I, R} -> {I, R};
                   _ -> ?ERR(bad_property_id)
               end,
    {Name, Type} = prop_by_id(Id),
    {Value, R1} = decode_prop_value(Type, R0),
    Acc1 = case {Name, Acc} of
               {user_property, #{user_property := L}} -> Acc#{user_property := L ++ [Value]};
               {user_property, _} -> Acc#{user_property => [Value]};
               {subscription_identifier, _} when Value =:= 0 ->
                   ?ERR(bad_subscription_identifier);
               {subscription_identifier, #{subscription_identifier := L}} ->
                   Acc#{subscription_identifier := L ++ [Value]};
               {subscription_identifier, _} -> Acc#{subscription_identifier => [Value]};
               {_, #{Name := _}} -> ?ERR({duplicate_property, Name});
               _ -> Acc#{Name => Value}
           end,
    decode_prop_list(R1, Acc1).

decode_prop_value(bool, <<V, R/binary>>) when V =< 1 -> {V, R};
decode_prop_value(u16, <<V:16, R/binary>>) -> {V, R};
decode_prop_value(u32, <<V:32, R/binary>>) -> {V, R};
decode_prop_value(varint, Bin) ->
    case decode_varint(Bin) of
        {ok, V, R} -> {V, R};
        _ -> ?ERR(bad_property_value)
    end;
decode_prop_value(utf8, Bin) -> utf8(Bin);
decode_prop_value(bin, Bin) -> bin(Bin);
decode_prop_value(pair, Bin) ->
    {K, R0} = utf8(Bin),
    {V, R1} = utf8(R0),
    {{K, V}, R1};
decode_prop_value(_, _) ->
    ?ERR(bad_property_value).

%%====================================================================
%% Decoding
%%====================================================================

%% @doc A stream parser for one connection. Options: `version' (default
%% v311; the peer's protocol, CONNECT packets carry their own) and
%% `max_packet_size' in bytes, fixed header included (default the MQTT limit).
-spec parser(#{version => version(), max_packet_size => pos_integer()}) -> parser().
parser(Opts) ->
    #parser{version = maps:get(version, Opts, v311),
            max = maps:get(max_packet_size, Opts, ?MAX_SIZE)}.

%% @doc Feeds bytes to the parser; returns the complete packets in order.
%% After an error the connection's byte stream cannot be resynchronised.
-spec parse(binary(), parser()) -> {ok, [packet()], parser()} | {error, reason()}.
parse(Data, #parser{need = 0, buf = <<>>} = P) ->
    parse_loop(Data, P, []);
parse(Data, #parser{need = 0, buf = Buf} = P) ->
    parse_loop(<<Buf/binary, Data/binary>>, P#parser{buf = <<>>}, []);
parse(Data, #parser{need = Need, chunks = Chunks, chunks_size = Size} = P) ->
    Size1 = Size + byte_size(Data),
    case Size1 >= Need of
        true ->
            Bin = iolist_to_binary(lists:reverse(Chunks, [Data])),
            parse_loop(Bin, P#parser{need = 0, chunks = [], chunks_size = 0}, []);
        false ->
            {ok, [], P#parser{chunks = [Data | Chunks], chunks_size = Size1}}
    end.

parse_loop(<<>>, P, Acc) ->
    {ok, lists:reverse(Acc), P#parser{buf = <<>>}};
parse_loop(<<Byte, Rest/binary>> = Bin, #parser{version = V, max = Max} = P, Acc) ->
    case decode_varint(Rest) of
        {ok, Len, Body0} ->
            Total = Len + byte_size(Bin) - byte_size(Body0),
            if
                Total > Max ->
                    {error, {packet_too_large, Total, Max}};
                byte_size(Body0) >= Len ->
                    <<Body:Len/binary, Rest1/binary>> = Body0,
                    case decode_body(Byte bsr 4, Byte band 15, Body, V) of
                        {ok, Packet} -> parse_loop(Rest1, P, [Packet | Acc]);
                        {error, _} = E -> E
                    end;
                true ->
                    {ok, lists:reverse(Acc),
                     P#parser{buf = <<>>, need = Total, chunks = [Bin],
                              chunks_size = byte_size(Bin)}}
            end;
        more when byte_size(Bin) >= 5 ->
            {error, bad_remaining_length};
        more ->
            {ok, lists:reverse(Acc), P#parser{buf = Bin}};
        {error, _} ->
            {error, bad_remaining_length}
    end.

%% @doc Decodes one packet at the head of a binary (no size limit).
-spec decode(binary(), version()) ->
          {ok, packet(), binary()} | more | {error, reason()}.
decode(Bin, V) ->
    decode(Bin, V, ?MAX_SIZE).

%% @doc Decodes one packet at the head of a binary, with a size limit.
-spec decode(binary(), version(), pos_integer()) ->
          {ok, packet(), binary()} | more | {error, reason()}.
decode(<<Byte, Rest/binary>> = Bin, V, Max) ->
    case decode_varint(Rest) of
        {ok, Len, Body0} ->
            Total = Len + byte_size(Bin) - byte_size(Body0),
            if
                Total > Max ->
                    {error, {packet_too_large, Total, Max}};
                byte_size(Body0) >= Len ->
                    <<Body:Len/binary, Rest1/binary>> = Body0,
                    case decode_body(Byte bsr 4, Byte band 15, Body, V) of
                        {ok, Packet} -> {ok, Packet, Rest1};
                        {error, _} = E -> E
                    end;
                true ->
                    more
            end;
        more when byte_size(Bin) >= 5 -> {error, bad_remaining_length};
        more -> more;
        {error, _} -> {error, bad_remaining_length}
    end;
decode(<<>>, _V, _Max) ->
    more.

decode_body(Type, Flags, Body, V) ->
    try
        {ok, body(Type, Flags, Body, V)}
    catch
        throw:{?MODULE, Reason} -> {error, {malformed, type_name(Type), Reason}}
    end.

type_name(T) ->
    element(T + 1, {reserved, connect, connack, publish, puback, pubrec, pubrel,
                    pubcomp, subscribe, suback, unsubscribe, unsuback, pingreq,
                    pingresp, disconnect, auth}).

%% PUBLISH first: the hot path.
body(3, Flags, Body, V) ->
    Dup = Flags band 8 =/= 0,
    QoS = (Flags bsr 1) band 3,
    Retain = Flags band 1 =:= 1,
    {Topic, R0} = case Body of
                      <<L:16, T:L/binary, TRest/binary>> -> {T, TRest};
                      _ -> ?ERR(truncated)
                  end,
    {Id, R1} = case QoS of
                   0 -> {undefined, R0};
                   3 -> ?ERR(bad_qos);
                   _ -> case R0 of
                            <<0:16, _/binary>> -> ?ERR(bad_packet_id);
                            <<I:16, R/binary>> -> {I, R};
                            _ -> ?ERR(truncated)
                        end
               end,
    {Props, Payload} = decode_props(V, R1),
    case Topic of
        <<>> when V =:= v5, is_map_key(topic_alias, Props) -> ok;
        <<>> -> ?ERR(empty_topic);
        _ -> topic_chars(Topic) orelse ?ERR(topic_error(Topic))
    end,
    #{type => publish, topic => Topic, payload => Payload, qos => QoS,
      retain => Retain, dup => Dup, packet_id => Id, properties => Props};
body(1, 0, Body, _V) ->
    decode_connect(Body);
body(2, 0, <<0:7, SP:1, RC, R/binary>>, V) ->
    {Props, Rest} = decode_props(V, R),
    ok = empty(Rest),
    SP =:= 1 andalso RC =/= 0 andalso ?ERR(session_present_with_error),
    V =:= v311 andalso RC > 5 andalso ?ERR({bad_reason_code, RC}),
    #{type => connack, session_present => SP =:= 1, reason_code => RC,
      properties => Props};
body(T, F, Body, V) when T >= 4, T =< 7 ->
    Type = type_name(T),
    F =:= (case T of 6 -> 2; _ -> 0 end) orelse ?ERR({bad_flags, F}),
    {Id, RC, Props} = case {V, Body} of
                          {_, <<0:16, _/binary>>} -> ?ERR(bad_packet_id);
                          {v311, <<I:16>>} -> {I, 0, #{}};
                          {v5, <<I:16>>} -> {I, 0, #{}};
                          {v5, <<I:16, C>>} -> {I, C, #{}};
                          {v5, <<I:16, C, R/binary>>} ->
                              {Pr, Rest} = decode_props(V, R),
                              ok = empty(Rest),
                              {I, C, Pr};
                          _ -> ?ERR(bad_length)
                      end,
    #{type => Type, packet_id => Id, reason_code => RC, properties => Props};
body(8, 2, Body, V) ->
    {Id, R0} = packet_id(Body),
    {Props, R1} = decode_props(V, R0),
    Topics = decode_sub_topics(R1, V, []),
    Topics =:= [] andalso ?ERR(no_topics),
    #{type => subscribe, packet_id => Id, topics => Topics, properties => Props};
body(9, 0, Body, V) ->
    {Id, R0} = packet_id(Body),
    {Props, R1} = decode_props(V, R0),
    RCs = binary_to_list(R1),
    V =:= v311 andalso lists:any(fun(C) -> not lists:member(C, [0, 1, 2, 16#80]) end, RCs)
        andalso ?ERR(bad_reason_code),
    #{type => suback, packet_id => Id, reason_codes => RCs, properties => Props};
body(10, 2, Body, V) ->
    {Id, R0} = packet_id(Body),
    {Props, R1} = decode_props(V, R0),
    Topics = decode_unsub_topics(R1, []),
    Topics =:= [] andalso ?ERR(no_topics),
    #{type => unsubscribe, packet_id => Id, topics => Topics, properties => Props};
body(11, 0, Body, v311) ->
    case Body of
        <<0:16>> -> ?ERR(bad_packet_id);
        <<Id:16>> -> #{type => unsuback, packet_id => Id, reason_codes => [],
                       properties => #{}};
        _ -> ?ERR(bad_length)
    end;
body(11, 0, Body, v5) ->
    {Id, R0} = packet_id(Body),
    {Props, R1} = decode_props(v5, R0),
    #{type => unsuback, packet_id => Id, reason_codes => binary_to_list(R1),
      properties => Props};
body(12, 0, <<>>, _V) ->
    #{type => pingreq};
body(13, 0, <<>>, _V) ->
    #{type => pingresp};
body(14, 0, <<>>, _V) ->
    #{type => disconnect, reason_code => 0, properties => #{}};
body(14, 0, <<RC>>, v5) ->
    #{type => disconnect, reason_code => RC, properties => #{}};
body(14, 0, <<RC, R/binary>>, v5) ->
    {Props, Rest} = decode_props(v5, R),
    ok = empty(Rest),
    #{type => disconnect, reason_code => RC, properties => Props};
body(15, 0, <<>>, v5) ->
    #{type => auth, reason_code => 0, properties => #{}};
body(15, 0, <<RC>>, v5) ->
    #{type => auth, reason_code => RC, properties => #{}};
body(15, 0, <<RC, R/binary>>, v5) ->
    {Props, Rest} = decode_props(v5, R),
    ok = empty(Rest),
    #{type => auth, reason_code => RC, properties => Props};
body(T, _F, _Body, V) when T =:= 0; T =:= 15, V =:= v311 ->
    ?ERR(reserved_packet_type);
body(T, F, _Body, _V) when (T =:= 8 orelse T =:= 10) andalso F =/= 2 ->
    ?ERR({bad_flags, F});
body(T, F, _Body, _V) when T =/= 8, T =/= 10, F =/= 0 ->
    ?ERR({bad_flags, F});
body(_T, _F, _Body, _V) ->
    ?ERR(bad_length).

decode_connect(Body) ->
    {Name, R0} = utf8(Body),
    {V, R1} = case {Name, R0} of
                  {<<"MQTT">>, <<4, R/binary>>} -> {v311, R};
                  {<<"MQTT">>, <<5, R/binary>>} -> {v5, R};
                  _ -> ?ERR(unsupported_protocol)
              end,
    <<UF:1, PF:1, WR:1, WQ:2, WF:1, Clean:1, Reserved:1, KA:16, R2/binary>> =
        case R1 of
            <<_:8, _:16, _/binary>> -> R1;
            _ -> ?ERR(truncated)
        end,
    Reserved =:= 0 orelse ?ERR(reserved_flag),
    WQ =:= 3 andalso ?ERR(bad_will_qos),
    WF =:= 0 andalso (WQ =/= 0 orelse WR =/= 0) andalso ?ERR(will_flags_without_will),
    V =:= v311 andalso UF =:= 0 andalso PF =:= 1 andalso ?ERR(password_without_username),
    {Props, R3} = decode_props(V, R2),
    {ClientId, R4} = utf8(R3),
    {Will, R5} = case WF of
                     0 ->
                         {undefined, R4};
                     1 ->
                         {WProps, W0} = decode_props(V, R4),
                         {WT, W1} = utf8(W0),
                         ok = no_wildcards(WT),
                         WT =:= <<>> andalso ?ERR(empty_topic),
                         {WP, W2} = bin(W1),
                         {#{topic => WT, payload => WP, qos => WQ, retain => WR =:= 1,
                            properties => WProps}, W2}
                 end,
    {User, R6} = case UF of 0 -> {undefined, R5}; 1 -> utf8(R5) end,
    {Pass, R7} = case PF of 0 -> {undefined, R6}; 1 -> bin(R6) end,
    ok = empty(R7),
    P0 = #{type => connect, proto => V, clean_start => Clean =:= 1, keepalive => KA,
           client_id => ClientId, properties => Props},
    maps:merge(P0, maps:filter(fun(_, X) -> X =/= undefined end,
                               #{username => User, password => Pass, will => Will})).

decode_sub_topics(<<>>, _V, Acc) ->
    lists:reverse(Acc);
decode_sub_topics(Bin, V, Acc) ->
    {Filter, R0} = utf8(Bin),
    ok = filter_ok(Filter),
    case {V, R0} of
        {v311, <<0:6, Q:2, R/binary>>} when Q < 3 ->
            decode_sub_topics(R, V, [{Filter, #{qos => Q, no_local => false,
                                                retain_as_published => false,
                                                retain_handling => 0}} | Acc]);
        {v5, <<0:2, RH:2, RAP:1, NL:1, Q:2, R/binary>>} when Q < 3, RH < 3 ->
            decode_sub_topics(R, V, [{Filter, #{qos => Q, no_local => NL =:= 1,
                                                retain_as_published => RAP =:= 1,
                                                retain_handling => RH}} | Acc]);
        _ ->
            ?ERR(bad_subscription_options)
    end.

decode_unsub_topics(<<>>, Acc) ->
    lists:reverse(Acc);
decode_unsub_topics(Bin, Acc) ->
    {Filter, R} = utf8(Bin),
    ok = filter_ok(Filter),
    decode_unsub_topics(R, [Filter | Acc]).

packet_id(<<0:16, _/binary>>) -> ?ERR(bad_packet_id);
packet_id(<<Id:16, R/binary>>) -> {Id, R};
packet_id(_) -> ?ERR(truncated).

utf8(<<L:16, S:L/binary, R/binary>>) ->
    case valid_utf8(S) of
        true -> {S, R};
        false -> ?ERR(bad_utf8)
    end;
utf8(_) ->
    ?ERR(truncated).

bin(<<L:16, S:L/binary, R/binary>>) -> {S, R};
bin(_) -> ?ERR(truncated).

empty(<<>>) -> ok;
empty(_) -> ?ERR(trailing_bytes).

no_wildcards(Topic) ->
    case binary:match(Topic, [<<"+">>, <<"#">>]) of
        nomatch -> ok;
        _ -> ?ERR(wildcard_in_topic_name)
    end.

filter_ok(F) ->
    case validate_topic_filter(F) of
        ok -> ok;
        {error, R} -> ?ERR(R)
    end.

%%====================================================================
%% Validation
%%====================================================================

%% @doc Well-formed UTF-8 without U+0000, as MQTT strings must be
%% (surrogates and overlong forms are rejected by the binary matcher).
-spec valid_utf8(binary()) -> boolean().
valid_utf8(<<C, R/binary>>) when C > 0, C < 128 -> valid_utf8(R);
valid_utf8(<<C/utf8, R/binary>>) when C > 127 -> valid_utf8(R);
valid_utf8(<<>>) -> true;
valid_utf8(_) -> false.

%% @doc A topic name a client may publish to: 1..65535 bytes of UTF-8, no
%% wildcards.
-spec validate_topic_name(term()) -> ok | {error, reason()}.
validate_topic_name(T) when is_binary(T), byte_size(T) > 0, byte_size(T) < 65536 ->
    case topic_chars(T) of
        true -> ok;
        false -> {error, topic_error(T)}
    end;
validate_topic_name(_) ->
    {error, bad_topic_name}.

%% One pass for the common case: UTF-8, no U+0000, no wildcard.
topic_chars(<<C, R/binary>>) when C > 0, C < 128, C =/= $+, C =/= $# -> topic_chars(R);
topic_chars(<<C/utf8, R/binary>>) when C > 127 -> topic_chars(R);
topic_chars(<<>>) -> true;
topic_chars(_) -> false.

topic_error(T) ->
    case valid_utf8(T) of
        false -> bad_utf8;
        true -> wildcard_in_topic_name
    end.

%% @doc A topic filter: `#' only as the whole last level, `+' only as a
%% whole level.
-spec validate_topic_filter(term()) -> ok | {error, reason()}.
validate_topic_filter(F) when is_binary(F), byte_size(F) > 0, byte_size(F) < 65536 ->
    case valid_utf8(F) of
        false -> {error, bad_utf8};
        true -> levels_ok(binary:split(F, <<"/">>, [global]))
    end;
validate_topic_filter(_) ->
    {error, bad_topic_filter}.

levels_ok([<<"#">>]) -> ok;
levels_ok([]) -> ok;
levels_ok([<<"+">> | R]) -> levels_ok(R);
levels_ok([L | R]) ->
    case binary:match(L, [<<"+">>, <<"#">>]) of
        nomatch -> levels_ok(R);
        _ -> {error, bad_topic_filter}
    end.

%% @doc A readable name for a CONNACK/SUBACK/PUBACK/DISCONNECT reason code
%% (5.0 codes; 3.1.1 CONNACK codes 1-5 are mapped to their meaning too when
%% given as `{v311, Code}').
-spec reason_name(byte() | {v311, byte()}) -> atom().
reason_name({v311, 1}) -> unacceptable_protocol_version;
reason_name({v311, 2}) -> identifier_rejected;
reason_name({v311, 3}) -> server_unavailable;
reason_name({v311, 4}) -> bad_username_or_password;
reason_name({v311, 5}) -> not_authorized;
reason_name({v311, C}) -> reason_name(C);
reason_name(16#00) -> success;
reason_name(16#01) -> granted_qos_1;
reason_name(16#02) -> granted_qos_2;
reason_name(16#04) -> disconnect_with_will;
reason_name(16#10) -> no_matching_subscribers;
reason_name(16#11) -> no_subscription_existed;
reason_name(16#80) -> unspecified_error;
reason_name(16#81) -> malformed_packet;
reason_name(16#82) -> protocol_error;
reason_name(16#83) -> implementation_specific_error;
reason_name(16#84) -> unsupported_protocol_version;
reason_name(16#85) -> client_identifier_not_valid;
reason_name(16#86) -> bad_username_or_password;
reason_name(16#87) -> not_authorized;
reason_name(16#88) -> server_unavailable;
reason_name(16#89) -> server_busy;
reason_name(16#8A) -> banned;
reason_name(16#8B) -> server_shutting_down;
reason_name(16#8C) -> bad_authentication_method;
reason_name(16#8D) -> keep_alive_timeout;
reason_name(16#8E) -> session_taken_over;
reason_name(16#8F) -> topic_filter_invalid;
reason_name(16#90) -> topic_name_invalid;
reason_name(16#91) -> packet_identifier_in_use;
reason_name(16#92) -> packet_identifier_not_found;
reason_name(16#93) -> receive_maximum_exceeded;
reason_name(16#94) -> topic_alias_invalid;
reason_name(16#95) -> packet_too_large;
reason_name(16#96) -> message_rate_too_high;
reason_name(16#97) -> quota_exceeded;
reason_name(16#98) -> administrative_action;
reason_name(16#99) -> payload_format_invalid;
reason_name(16#9A) -> retain_not_supported;
reason_name(16#9B) -> qos_not_supported;
reason_name(16#9C) -> use_another_server;
reason_name(16#9D) -> server_moved;
reason_name(16#9E) -> shared_subscriptions_not_supported;
reason_name(16#9F) -> connection_rate_exceeded;
reason_name(16#A0) -> maximum_connect_time;
reason_name(16#A1) -> subscription_identifiers_not_supported;
reason_name(16#A2) -> wildcard_subscriptions_not_supported;
reason_name(_) -> unknown_reason_code.
