%% @doc Internal. The `humidifier' family (HA `humidifier', device class
%% humidifier or dehumidifier): TurnHumidifierOn/Off, SetTargetHumidity,
%% SetHumidifierMode; streams HumidifierState, HumidifierTargetHumidity,
%% HumidifierMode, HumidifierCurrentHumidity, HumidifierAction;
%% ReadHumidifier. docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_humidifier).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() ->
    [{<<"hum_cmd_t">>, <<"target_humidity_command_topic">>},
     {<<"hum_stat_t">>, <<"target_humidity_state_topic">>},
     {<<"hum_state_tpl">>, <<"target_humidity_state_template">>},
     {<<"min_hum">>, <<"min_humidity">>}, {<<"max_hum">>, <<"max_humidity">>},
     {<<"mode_cmd_t">>, <<"mode_command_topic">>}, {<<"mode_stat_t">>, <<"mode_state_topic">>},
     {<<"mode_stat_tpl">>, <<"mode_state_template">>},
     {<<"curr_hum_t">>, <<"current_humidity_topic">>},
     {<<"curr_hum_tpl">>, <<"current_humidity_template">>},
     {<<"act_t">>, <<"action_topic">>}, {<<"act_tpl">>, <<"action_template">>},
     {<<"hum_cmd_tpl">>, <<"target_humidity_command_template">>},
     {<<"mode_cmd_tpl">>, <<"mode_command_template">>}].

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        Num = fun(K, D) -> mqtt_avatar_ha:number(K, C, D) end,
        Specs = [{<<"TargetHumidity">>, <<"SetTargetHumidity">>, <<"target_humidity_command_topic">>,
                  <<"target_humidity_state_topic">>, <<"target_humidity_state_template">>,
                  mqtt_avatar_part:range(Num(<<"min_humidity">>, <<"0">>),
                                         Num(<<"max_humidity">>, <<"100">>))},
                 {<<"Mode">>, <<"SetHumidifierMode">>, <<"mode_command_topic">>,
                  <<"mode_state_topic">>, <<"mode_state_template">>,
                  mqtt_avatar_part:one_of(mqtt_avatar_ha:strings(<<"modes">>, C))},
                 {<<"CurrentHumidity">>, <<>>, undefined, <<"current_humidity_topic">>,
                  <<"current_humidity_template">>, <<>>},
                 {<<"Action">>, <<>>, undefined, <<"action_topic">>, <<"action_template">>, <<>>}],
        case mqtt_avatar_ha:settings(C, Specs) of
            {ok, Settings} ->
                {ok, maps:merge(Base#{json_command => false, settings => Settings},
                                mqtt_avatar_ha:on_off(C))};
            {error, _} = E -> E
        end
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{settings := Settings} = E, Ctx) ->
    Caps = [{<<"Humidifier">>, <<"yes">>}]
        ++ [{<<"DeviceClass">>, C} || C <- [maps:get(device_class, E)], is_binary(C)],
    #{services := OnOff} = mqtt_avatar_part:on_off(E, Ctx, {<<"TurnHumidifierOn">>,
                                                            <<"TurnHumidifierOff">>},
                                                   Caps, <<"State">>, <<"Humidifier">>),
    {Services, Reads} = mqtt_avatar_part:settings(Settings, Caps, Ctx),
    State = case maps:get(state_topic, E) of
                undefined -> [];
                T -> [{<<"State">>, #{topic => T, source => maps:get(value, E)},
                       mqtt_avatar_part:on_off_map(E, <<"on">>, <<"off">>)}]
            end,
    mqtt_avatar_part:family(<<"Humidifier">>, OnOff ++ Services, State ++ Reads, E, Ctx).
