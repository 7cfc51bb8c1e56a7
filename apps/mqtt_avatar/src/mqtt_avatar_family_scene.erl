%% @doc Internal. The `scene' family (HA `scene'): `Activate<Name>' (with
%% `Scene' the name) publishes `payload_on'. docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_scene).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        {ok, Base#{on => mqtt_avatar_ha:str(<<"payload_on">>, C, <<"ON">>)}}
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{command_topic := Topic, on := On} = E, Ctx) ->
    Name = mqtt_avatar_part:camel(mqtt_avatar_part:first_name([maps:get(name, E), <<"Scene">>])),
    Service = mqtt_avatar_part:fixed(<<"Activate", Name/binary>>,
                                     [{<<"Scene">>, Name}], #{topic => Topic, field => undefined},
                                     On, undefined, Ctx),
    mqtt_avatar_part:actuator([Service], Ctx, <<"Scene">>).
