%% @doc Internal. The `climate' family (HA `climate', zigbee2mqtt's
%% `climate' expose): thermostats, heat pumps, air conditioners. A
%% service per setting (SetHvacMode, SetTargetTemperature, ...Low, ...High,
%% SetFanMode, SetSwingMode, SetClimatePresetMode, SetTargetHumidity),
%% TurnClimateOn/Off with a power topic, a stream per value read
%% (Climate<Param>, with CurrentTemperature, HvacAction, CurrentHumidity),
%% ReadClimate. docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_climate).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, from_z2m/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() ->
    [{<<"act_t">>, <<"action_topic">>}, {<<"act_tpl">>, <<"action_template">>},
     {<<"curr_temp_t">>, <<"current_temperature_topic">>},
     {<<"curr_temp_tpl">>, <<"current_temperature_template">>},
     {<<"curr_hum_t">>, <<"current_humidity_topic">>},
     {<<"curr_hum_tpl">>, <<"current_humidity_template">>},
     {<<"fan_mode_cmd_t">>, <<"fan_mode_command_topic">>},
     {<<"fan_mode_stat_t">>, <<"fan_mode_state_topic">>},
     {<<"fan_mode_stat_tpl">>, <<"fan_mode_state_template">>},
     {<<"mode_cmd_t">>, <<"mode_command_topic">>}, {<<"mode_stat_t">>, <<"mode_state_topic">>},
     {<<"mode_stat_tpl">>, <<"mode_state_template">>},
     {<<"pow_cmd_t">>, <<"power_command_topic">>},
     {<<"pr_mode_cmd_t">>, <<"preset_mode_command_topic">>},
     {<<"pr_mode_stat_t">>, <<"preset_mode_state_topic">>},
     {<<"pr_mode_val_tpl">>, <<"preset_mode_value_template">>},
     {<<"pr_modes">>, <<"preset_modes">>},
     {<<"swing_mode_cmd_t">>, <<"swing_mode_command_topic">>},
     {<<"swing_mode_stat_t">>, <<"swing_mode_state_topic">>},
     {<<"swing_mode_stat_tpl">>, <<"swing_mode_state_template">>},
     {<<"temp_cmd_t">>, <<"temperature_command_topic">>},
     {<<"temp_stat_t">>, <<"temperature_state_topic">>},
     {<<"temp_stat_tpl">>, <<"temperature_state_template">>},
     {<<"temp_lo_cmd_t">>, <<"temperature_low_command_topic">>},
     {<<"temp_lo_stat_t">>, <<"temperature_low_state_topic">>},
     {<<"temp_lo_stat_tpl">>, <<"temperature_low_state_template">>},
     {<<"temp_hi_cmd_t">>, <<"temperature_high_command_topic">>},
     {<<"temp_hi_stat_t">>, <<"temperature_high_state_topic">>},
     {<<"temp_hi_stat_tpl">>, <<"temperature_high_state_template">>},
     {<<"temp_unit">>, <<"temperature_unit">>}, {<<"temp_step">>, <<"temp_step">>},
     {<<"hum_cmd_t">>, <<"target_humidity_command_topic">>},
     {<<"hum_stat_t">>, <<"target_humidity_state_topic">>},
     {<<"hum_state_tpl">>, <<"target_humidity_state_template">>},
     {<<"min_hum">>, <<"min_humidity">>}, {<<"max_hum">>, <<"max_humidity">>},
     {<<"pl_on">>, <<"payload_on">>}, {<<"pl_off">>, <<"payload_off">>},
     {<<"mode_cmd_tpl">>, <<"mode_command_template">>},
     {<<"temp_cmd_tpl">>, <<"temperature_command_template">>},
     {<<"temp_lo_cmd_tpl">>, <<"temperature_low_command_template">>},
     {<<"temp_hi_cmd_tpl">>, <<"temperature_high_command_template">>},
     {<<"fan_mode_cmd_tpl">>, <<"fan_mode_command_template">>},
     {<<"swing_mode_cmd_tpl">>, <<"swing_mode_command_template">>},
     {<<"pr_mode_cmd_tpl">>, <<"preset_mode_command_template">>},
     {<<"hum_cmd_tpl">>, <<"target_humidity_command_template">>},
     {<<"pow_cmd_tpl">>, <<"power_command_template">>}].

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    Num = fun(K, D) -> mqtt_avatar_ha:number(K, C, D) end,
    Modes = fun(K, D) -> case mqtt_avatar_ha:strings(K, C) of
                             undefined -> mqtt_avatar_part:one_of(D);
                             L -> mqtt_avatar_part:one_of(L)
                         end
            end,
    Temp = mqtt_avatar_part:range(Num(<<"min_temp">>, <<"7">>), Num(<<"max_temp">>, <<"35">>)),
    Hum = mqtt_avatar_part:range(Num(<<"min_humidity">>, <<"30">>), Num(<<"max_humidity">>, <<"99">>)),
    Specs = [{<<"HvacMode">>, <<"SetHvacMode">>, <<"mode_command_topic">>, <<"mode_state_topic">>,
              <<"mode_state_template">>,
              Modes(<<"modes">>, [<<"auto">>, <<"off">>, <<"cool">>, <<"heat">>, <<"dry">>,
                                  <<"fan_only">>])},
             {<<"TargetTemperature">>, <<"SetTargetTemperature">>, <<"temperature_command_topic">>,
              <<"temperature_state_topic">>, <<"temperature_state_template">>, Temp},
             {<<"TargetTemperatureLow">>, <<"SetTargetTemperatureLow">>,
              <<"temperature_low_command_topic">>, <<"temperature_low_state_topic">>,
              <<"temperature_low_state_template">>, Temp},
             {<<"TargetTemperatureHigh">>, <<"SetTargetTemperatureHigh">>,
              <<"temperature_high_command_topic">>, <<"temperature_high_state_topic">>,
              <<"temperature_high_state_template">>, Temp},
             {<<"FanMode">>, <<"SetFanMode">>, <<"fan_mode_command_topic">>,
              <<"fan_mode_state_topic">>, <<"fan_mode_state_template">>,
              Modes(<<"fan_modes">>, [<<"auto">>, <<"low">>, <<"medium">>, <<"high">>])},
             {<<"SwingMode">>, <<"SetSwingMode">>, <<"swing_mode_command_topic">>,
              <<"swing_mode_state_topic">>, <<"swing_mode_state_template">>,
              Modes(<<"swing_modes">>, [<<"on">>, <<"off">>])},
             {<<"PresetMode">>, <<"SetClimatePresetMode">>, <<"preset_mode_command_topic">>,
              <<"preset_mode_state_topic">>, <<"preset_mode_value_template">>,
              Modes(<<"preset_modes">>, undefined)},
             {<<"TargetHumidity">>, <<"SetTargetHumidity">>, <<"target_humidity_command_topic">>,
              <<"target_humidity_state_topic">>, <<"target_humidity_state_template">>, Hum},
             {<<"CurrentTemperature">>, <<>>, undefined, <<"current_temperature_topic">>,
              <<"current_temperature_template">>, <<>>},
             {<<"CurrentHumidity">>, <<>>, undefined, <<"current_humidity_topic">>,
              <<"current_humidity_template">>, <<>>},
             {<<"HvacAction">>, <<>>, undefined, <<"action_topic">>, <<"action_template">>, <<>>}],
    case {mqtt_avatar_ha:settings(C, Specs),
          mqtt_avatar_ha:read(C, [{power, {control, <<"power_command_topic">>}}])} of
        {{ok, []}, {ok, P}} when map_size(P) =:= 0 ->
            {error, <<"a climate needs a command or state topic (mode_command_topic...)">>};
        {{ok, Settings}, {ok, P}} ->
            {ok, Base#{settings => Settings, power => maps:get(power, P, undefined),
                       payloads => #{on => mqtt_avatar_ha:str(<<"payload_on">>, C, <<"ON">>),
                                     off => mqtt_avatar_ha:str(<<"payload_off">>, C, <<"OFF">>)},
                       unit => mqtt_avatar_ha:str(<<"temperature_unit">>, C)}};
        {{error, _} = E, _} -> E;
        {_, {error, _} = E} -> E
    end.

%% zigbee2mqtt's climate features, by name: the value each is.
-define(Z2M, [{<<"system_mode">>, <<"HvacMode">>, <<"SetHvacMode">>},
              {<<"occupied_heating_setpoint">>, <<"TargetTemperature">>, <<"SetTargetTemperature">>},
              {<<"current_heating_setpoint">>, <<"TargetTemperature">>, <<"SetTargetTemperature">>},
              {<<"occupied_cooling_setpoint">>, <<"TargetTemperatureHigh">>,
               <<"SetTargetTemperatureHigh">>},
              {<<"local_temperature">>, <<"CurrentTemperature">>, <<>>},
              {<<"running_state">>, <<"HvacAction">>, <<>>},
              {<<"fan_mode">>, <<"FanMode">>, <<"SetFanMode">>},
              {<<"swing_mode">>, <<"SwingMode">>, <<"SetSwingMode">>},
              {<<"preset">>, <<"PresetMode">>, <<"SetClimatePresetMode">>}]).

%% @doc The entity of a zigbee2mqtt `climate' expose (features
%% `system_mode', `occupied_heating_setpoint', `local_temperature'...).
-spec from_z2m(map(), mqtt_avatar_z2m:ctx()) -> [mqtt_avatar_discovery:entity()].
from_z2m(#{<<"features">> := Features}, Ctx) when is_list(Features) ->
    %% One setting per value: Eurotronic's SPZB0001 exposes both
    %% occupied_heating_setpoint and current_heating_setpoint, and the
    %% first is the target temperature (two would repeat its parameter).
    %% A value without a service (running_state, which Tuya and AVATTO
    %% TRVs mark settable) is only read: a control would be a service
    %% without a ServiceType.
    Settings = first_per_param(
                 [read_only(S, Service)
                  || #{<<"name">> := Name} = F <- Features, is_map(F),
                     {N, Param, Service} <- ?Z2M, N =:= Name,
                     S <- mqtt_avatar_z2m:setting(F, Param, Service, Ctx)]),
    case Settings of
        [] -> [];
        _ -> [(mqtt_avatar_z2m:entity(climate, <<"climate">>, Ctx))#{settings => Settings,
                                                                     power => undefined,
                                                                     payloads => #{}}]
    end;
from_z2m(_, _Ctx) ->
    [].

read_only(S, <<>>) -> maps:remove(control, S);
read_only(S, _Service) -> S.

first_per_param(Settings) ->
    {Kept, _} = lists:foldl(fun(#{param := P} = S, {Acc, Seen}) ->
                                    case maps:is_key(P, Seen) of
                                        true -> {Acc, Seen};
                                        false -> {[S | Acc], Seen#{P => true}}
                                    end
                            end, {[], #{}}, Settings),
    lists:reverse(Kept).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{settings := Settings, power := Power, payloads := Pl} = E, Ctx) ->
    Caps = [{<<"Climate">>, <<"yes">>}]
        ++ [{<<"Unit">>, U} || U <- [maps:get(unit, E, undefined)], is_binary(U)],
    {Services, Reads} = mqtt_avatar_part:settings(Settings, Caps, Ctx),
    OnOff = [mqtt_avatar_part:fixed(Type, Caps, Power, maps:get(Key, Pl), undefined, Ctx)
             || Power =/= undefined,
                {Type, Key} <- [{<<"TurnClimateOn">>, on}, {<<"TurnClimateOff">>, off}]],
    mqtt_avatar_part:family(<<"Climate">>, Services ++ OnOff, Reads, E, Ctx).
