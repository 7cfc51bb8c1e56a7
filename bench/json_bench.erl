%% @doc CPU time of the JSON work of the device side, through evatar_json
%% (Debian's jiffy): a zigbee2mqtt state payload decoded and a light command
%% encoded 100,000 times, a device list of 1,000 lights (about 420 kB)
%% decoded and encoded 50 times. CPU ms are statistics(runtime), the VM's
%% CPU time (jiffy's NIF included), so the figure does not count other
%% programs of a shared machine. `{codec, M}' times any module with
%% decode/1 and encode/1 instead. Not part of the product.
-module(json_bench).

-export([main/0, main/1]).

%% @equiv main([])
-spec main() -> ok.
main() -> main([]).

%% @doc Prints one line a workload.
-spec main([{codec, module()}]) -> ok.
main(Options) ->
    M = proplists:get_value(codec, Options, evatar_json),
    io:format("JSON on the device side: OTP ~s, codec ~s~n", [erlang:system_info(otp_release), M]),
    State = <<"{\"state\":\"ON\",\"brightness\":254,\"color_temp\":370,\"color\":{\"x\":0.4573,\"y\":0.41},"
              "\"linkquality\":87,\"power_on_behavior\":\"previous\",\"update\":{\"state\":\"idle\"},"
              "\"temperature\":21.5,\"humidity\":48.25,\"battery\":100,\"voltage\":3015}">>,
    Cmd = #{<<"state">> => <<"ON">>, <<"brightness">> => 200, <<"transition">> => 0.5,
            <<"color">> => #{<<"x">> => 0.701, <<"y">> => 0.299}},
    Dev = fun(I) -> #{<<"friendly_name">> => iolist_to_binary(io_lib:format("room_~b_light", [I])),
                      <<"ieee_address">> => iolist_to_binary(io_lib:format("0x~16.16.0b", [I])),
                      <<"type">> => <<"Router">>,
                      <<"definition">> => #{<<"model">> => <<"LED1545G12">>, <<"vendor">> => <<"IKEA">>,
                          <<"description">> => <<"TRADFRI bulb E27, white spectrum">>,
                          <<"exposes">> => [#{<<"type">> => <<"light">>, <<"features">> =>
                              [#{<<"type">> => <<"binary">>, <<"name">> => <<"state">>, <<"property">> => <<"state">>,
                                 <<"access">> => 7, <<"value_on">> => <<"ON">>, <<"value_off">> => <<"OFF">>},
                               #{<<"type">> => <<"numeric">>, <<"name">> => <<"brightness">>, <<"property">> => <<"brightness">>,
                                 <<"access">> => 7, <<"value_min">> => 0, <<"value_max">> => 254}]}]}} end,
    List = iolist_to_binary(M:encode([Dev(I) || I <- lists:seq(1, 1000)])),
    {ok, _} = M:decode(List),
    Rows = [{"decode state payload x100000", cpu(fun() -> [{ok, _} = M:decode(State) || _ <- lists:seq(1, 100000)] end)},
         {"encode command x100000", cpu(fun() -> [iolist_to_binary(M:encode(Cmd)) || _ <- lists:seq(1, 100000)] end)},
         {io_lib:format("decode device list (~b kB) x50", [byte_size(List) div 1024]), cpu(fun() -> [{ok, _} = M:decode(List) || _ <- lists:seq(1, 50)] end)},
         {"encode device list x50", cpu(fun() -> [iolist_to_binary(M:encode([Dev(I) || I <- lists:seq(1, 1000)])) || _ <- lists:seq(1, 50)] end)}],
    _ = [io:format("~-44s ~6b ms CPU~n", [L, T]) || {L, T} <- Rows],
    ok.

cpu(F) ->
    true = garbage_collect(),
    {T0, _} = statistics(runtime),
    _ = F(),
    {T1, _} = statistics(runtime),
    T1 - T0.
