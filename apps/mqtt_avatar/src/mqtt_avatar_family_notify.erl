%% @doc Internal. The `notify' family (HA `notify'): one service whose
%% request parameter `Message' is the payload. docs/mqtt.md section 2.
-module(mqtt_avatar_family_notify).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(_C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() -> {ok, Base} end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, Ctx) ->
    mqtt_avatar_part:payload_service(E, Ctx, <<"Notify">>, <<"Message">>, none).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].
