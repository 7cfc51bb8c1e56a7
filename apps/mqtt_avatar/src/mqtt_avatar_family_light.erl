%% @doc Internal. The `light' family (HA `light' in the default, json and
%% template schemas; zigbee2mqtt's `light' expose): TurnLightOn with
%% Brightness, ColorRGB/ColorHS/ColorXY, ColorTemp/ColorTempKelvin, Effect,
%% Transition as the light supports them, and TurnLightOff. The light's HA
%% config rides in `MqttLight'; mqtt_avatar_light makes its commands and
%% reads its states. docs/mqtt.md section 2.7.
-module(mqtt_avatar_family_light).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        Config = maps:with(mqtt_avatar_light:config_keys(), C),
        case mqtt_avatar_light:config(Config) of
            {ok, _} -> {ok, maps:merge(Base#{light => Config}, mqtt_avatar_ha:on_off(C))};
            {error, M} -> {error, M}
        end
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{light := Config} = E, Ctx) ->
    {ok, L} = mqtt_avatar_light:config(Config),
    Json = evatar_json:encode(Config),
    Room = maps:get(room, Ctx),
    Attributes = [{<<"MqttAttributes">>, <<"all">>} || maps:get(attributes, E, false)],
    Caps = mqtt_avatar_light:capabilities(L),
    OffCaps = [P || {N, _} = P <- Caps, N =:= <<"Light">> orelse N =:= <<"Transition">>],
    Entry = fun(Type, Command, Capabilities) ->
                    mqtt_avatar_part:entry(<<"ACTUATOR">>, Type,
                                           Capabilities ++ Room
                                           ++ [{<<"MqttCommand">>, Command}, {<<"MqttLight">>, Json}]
                                           ++ Attributes)
            end,
    mqtt_avatar_part:actuator([Entry(<<"TurnLightOn">>, <<"light:on">>, Caps),
                               Entry(<<"TurnLightOff">>, <<"light:off">>, OffCaps)],
                              Ctx, <<"LightSwitch">>).

%% HA's abbreviations of the light keys.
-spec abbreviations() -> [{binary(), binary()}].
abbreviations() ->
    [{<<"bri_cmd_t">>, <<"brightness_command_topic">>},
     {<<"bri_cmd_tpl">>, <<"brightness_command_template">>},
     {<<"bri_scl">>, <<"brightness_scale">>}, {<<"bri_stat_t">>, <<"brightness_state_topic">>},
     {<<"bri_tpl">>, <<"brightness_template">>}, {<<"bri_val_tpl">>, <<"brightness_value_template">>},
     {<<"clr_temp_cmd_t">>, <<"color_temp_command_topic">>},
     {<<"clr_temp_cmd_tpl">>, <<"color_temp_command_template">>},
     {<<"clr_temp_stat_t">>, <<"color_temp_state_topic">>},
     {<<"clr_temp_tpl">>, <<"color_temp_template">>},
     {<<"clr_temp_val_tpl">>, <<"color_temp_value_template">>},
     {<<"clr_temp_k">>, <<"color_temp_kelvin">>},
     {<<"cmd_on_tpl">>, <<"command_on_template">>}, {<<"cmd_off_tpl">>, <<"command_off_template">>},
     {<<"fx_cmd_t">>, <<"effect_command_topic">>}, {<<"fx_cmd_tpl">>, <<"effect_command_template">>},
     {<<"fx_list">>, <<"effect_list">>}, {<<"fx_stat_t">>, <<"effect_state_topic">>},
     {<<"fx_tpl">>, <<"effect_template">>}, {<<"fx_val_tpl">>, <<"effect_value_template">>},
     {<<"hs_cmd_t">>, <<"hs_command_topic">>}, {<<"hs_cmd_tpl">>, <<"hs_command_template">>},
     {<<"hs_stat_t">>, <<"hs_state_topic">>}, {<<"hs_val_tpl">>, <<"hs_value_template">>},
     {<<"rgb_cmd_t">>, <<"rgb_command_topic">>}, {<<"rgb_cmd_tpl">>, <<"rgb_command_template">>},
     {<<"rgb_stat_t">>, <<"rgb_state_topic">>}, {<<"rgb_val_tpl">>, <<"rgb_value_template">>},
     {<<"xy_cmd_t">>, <<"xy_command_topic">>}, {<<"xy_cmd_tpl">>, <<"xy_command_template">>},
     {<<"xy_stat_t">>, <<"xy_state_topic">>}, {<<"xy_val_tpl">>, <<"xy_value_template">>},
     {<<"r_tpl">>, <<"red_template">>}, {<<"g_tpl">>, <<"green_template">>},
     {<<"b_tpl">>, <<"blue_template">>}, {<<"on_cmd_type">>, <<"on_command_type">>},
     {<<"min_mirs">>, <<"min_mireds">>}, {<<"max_mirs">>, <<"max_mireds">>},
     {<<"min_k">>, <<"min_kelvin">>}, {<<"max_k">>, <<"max_kelvin">>},
     {<<"sup_clrm">>, <<"supported_color_modes">>}].
