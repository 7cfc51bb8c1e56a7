%% @doc How an MQTT Avatar's description grows with the home: a zigbee2mqtt
%% network of 300, 3,000 and 30,000 devices (sensors, lights, plugs and
%% thermostats in turn) generated as the Avatar does when the device list
%% arrives (the description and its runtime spec), in ms per device,
%% beside the generator it replaced (mqtt_gen_bench_old, followed by a
%% second pass over the description for the spec, as the Avatar then did).
%% Reading the device list is timed apart: 30,000 devices are some 150 MB
%% of JSON, over the 64 MiB a device list may have, so every size reads
%% one device at a time. Not part of the product; docs/mqtt.md section 6
%% has the figures.
-module(mqtt_gen_bench).

-export([main/0, main/1]).

-define(SIZES, [300, 3000, 30000]).
%% The old generator only up to this size (30,000 devices: hours).
-define(OLD_MAX, 3000).
-define(BASE, <<"zigbee2mqtt">>).

%% @equiv main([])
-spec main() -> ok.
main() -> main([]).

%% @doc Prints the table. `quick': sizes 10 times smaller; `no_old':
%% without the old generator.
-spec main([quick | no_old]) -> ok.
main(Options) ->
    ok = logger:set_primary_config(level, warning),
    Scale = case lists:member(quick, Options) of true -> 10; false -> 1 end,
    io:format("MQTT Avatar generation: OTP ~s, ~b schedulers~n"
              "ms/device: wall time of generating the description and its spec, in a fresh "
              "process, / devices (one run)~n",
              [erlang:system_info(otp_release), erlang:system_info(schedulers_online)]),
    io:format("~8s ~10s ~12s ~12s ~10s ~12s~n",
              ["devices", "components", "new ms", "new ms/dev", "old ms/dev", "read ms/dev"]),
    lists:foreach(fun(N) -> row(N, Options) end, [S div Scale || S <- ?SIZES]).

row(N, Options) ->
    {ReadMs, Devices} = fresh(fun() -> timed(fun() -> devices(N) end) end),
    {NewMs, {Count, []}} = fresh(fun() -> timed(fun() -> new(Devices) end) end),
    Old = case N =< ?OLD_MAX andalso not lists:member(no_old, Options) of
              true ->
                  {OldMs, {Count, []}} = fresh(fun() -> timed(fun() -> old(Devices) end) end),
                  io_lib:format("~.2f", [OldMs / N]);
              false ->
                  "-"
          end,
    io:format("~8b ~10b ~12b ~12.2f ~10s ~12.2f~n", [N, Count, NewMs, NewMs / N, Old, ReadMs / N]).

new(Devices) ->
    {D, Spec, Problems} = mqtt_avatar_generate:build(#{entity_id => <<"bench">>}, Devices, []),
    #{components := Specs} = Spec,
    Count = length(Specs),
    Count = length(maps:get(components, D)),
    {Count, Problems}.

old(Devices) ->
    {D, Problems} = mqtt_gen_bench_old:description(#{entity_id => <<"bench">>}, Devices, []),
    {ok, #{components := Specs}} = mqtt_avatar_spec:from_description(D),
    {length(Specs), Problems}.

%% The network as discovery reads it (mqtt_avatar_z2m, one device at a time).
devices(N) ->
    [begin
         Json = evatar_json:encode([device(I)]),
         {ok, [D], []} = mqtt_avatar_z2m:parse(?BASE, Json),
         D
     end || I <- lists:seq(1, N)].

device(I) ->
    Name = iolist_to_binary(io_lib:format("room_~b_~s", [I div 4, kind(I rem 4)])),
    #{<<"type">> => <<"EndDevice">>,
      <<"friendly_name">> => Name,
      <<"ieee_address">> => iolist_to_binary(io_lib:format("0x~16.16.0b", [I])),
      <<"definition">> => definition(I rem 4)}.

kind(0) -> "sensor";
kind(1) -> "light";
kind(2) -> "plug";
kind(3) -> "thermostat".

definition(0) ->
    def(<<"WSDCGQ11LM">>, <<"Temperature, humidity and pressure sensor">>,
        [binary(<<"occupancy">>, 1), num(<<"temperature">>, <<"°C"/utf8>>, 1),
         num(<<"humidity">>, <<"%">>, 1), num(<<"pressure">>, <<"hPa">>, 1),
         num(<<"battery">>, <<"%">>, 1), num(<<"linkquality">>, <<"lqi">>, 1)]);
definition(1) ->
    def(<<"LED1545G12">>, <<"TRADFRI bulb E27, white spectrum">>,
        [#{<<"type">> => <<"light">>,
           <<"features">> =>
               [binary(<<"state">>, 7), num(<<"brightness">>, null, 7, 0, 254),
                num(<<"color_temp">>, <<"mired">>, 7, 250, 454)]},
         num(<<"linkquality">>, <<"lqi">>, 1)]);
definition(2) ->
    def(<<"SP 120">>, <<"Smart plug">>,
        [#{<<"type">> => <<"switch">>, <<"features">> => [binary(<<"state">>, 7)]},
         num(<<"power">>, <<"W">>, 1), num(<<"energy">>, <<"kWh">>, 1),
         num(<<"voltage">>, <<"V">>, 1), num(<<"linkquality">>, <<"lqi">>, 1)]);
definition(3) ->
    def(<<"TS0601_thermostat">>, <<"Radiator valve with thermostat">>,
        [num(<<"local_temperature">>, <<"°C"/utf8>>, 1),
         num(<<"current_heating_setpoint">>, <<"°C"/utf8>>, 7, 5, 30),
         #{<<"type">> => <<"enum">>, <<"name">> => <<"preset">>, <<"property">> => <<"preset">>,
           <<"access">> => 7, <<"values">> => [<<"manual">>, <<"schedule">>, <<"holiday">>]},
         num(<<"battery">>, <<"%">>, 1)]).

def(Model, Description, Exposes) ->
    #{<<"model">> => Model, <<"vendor">> => <<"Bench">>, <<"description">> => Description,
      <<"exposes">> => Exposes}.

binary(Name, Access) ->
    #{<<"type">> => <<"binary">>, <<"name">> => Name, <<"property">> => Name,
      <<"access">> => Access, <<"value_on">> => <<"ON">>, <<"value_off">> => <<"OFF">>}.

num(Name, Unit, Access) ->
    #{<<"type">> => <<"numeric">>, <<"name">> => Name, <<"property">> => Name,
      <<"access">> => Access, <<"unit">> => Unit}.

num(Name, Unit, Access, Min, Max) ->
    (num(Name, Unit, Access))#{<<"value_min">> => Min, <<"value_max">> => Max}.

fresh(Fun) ->
    Parent = self(),
    Tag = make_ref(),
    {Pid, Ref} = spawn_monitor(fun() -> Parent ! {Tag, Fun()} end),
    receive
        {Tag, Result} ->
            demonitor(Ref, [flush]),
            Result;
        {'DOWN', Ref, process, Pid, Reason} ->
            exit(Reason)
    end.

timed(Fun) ->
    T0 = erlang:monotonic_time(millisecond),
    R = Fun(),
    {erlang:monotonic_time(millisecond) - T0, R}.
