%% @doc Internal. The `switch' family (HA `switch', zigbee2mqtt's `switch'
%% expose): a socket switch for device class `outlet' (SwitchSocketOn/Off),
%% else SwitchOn/SwitchOff named after the switch. docs/mqtt.md section 2.
-module(mqtt_avatar_family_switch).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        {ok, maps:merge(Base#{json_command => false}, mqtt_avatar_ha:on_off(C))}
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{device_class := <<"outlet">>} = E, Ctx) ->
    mqtt_avatar_part:on_off(E, Ctx, {<<"SwitchSocketOn">>, <<"SwitchSocketOff">>},
                            [{<<"Appliance">>, <<"any">>}], <<"Socket">>, <<"SocketSwitch">>);
generate(E, Ctx) ->
    Name = mqtt_avatar_part:camel(mqtt_avatar_part:first_name([maps:get(name, E), <<"Switch">>])),
    mqtt_avatar_part:on_off(E, Ctx, {<<"SwitchOn">>, <<"SwitchOff">>},
                            [{<<"Switch">>, <<"yes">>}, {<<"Name">>, Name}],
                            <<"Switch">>, <<"Switch">>).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].
