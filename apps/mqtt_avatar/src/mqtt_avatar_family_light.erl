%% @doc Internal. The `light' family (HA `light', zigbee2mqtt's `light'
%% expose): TurnLightOn/TurnLightOff, JSON commands for `schema: json',
%% feedback `Light' on/off. docs/mqtt.md section 2.
-module(mqtt_avatar_family_light).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        Json = mqtt_avatar_ha:str(<<"schema">>, C) =:= <<"json">>,
        Value = case {Json, maps:get(value, Base)} of
                    {true, raw} -> {json, [<<"state">>]};
                    {_, V} -> V
                end,
        {ok, maps:merge(Base#{value := Value, json_command => Json}, mqtt_avatar_ha:on_off(C))}
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, Ctx) ->
    mqtt_avatar_part:on_off(E, Ctx, {<<"TurnLightOn">>, <<"TurnLightOff">>},
                            [{<<"Light">>, <<"yes">>}], <<"Light">>, <<"LightSwitch">>).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].
