%% @doc Internal. The `text' family (HA `text'): one service whose request
%% parameter `Text' is the payload, confirmed on the state topic.
%% docs/mqtt.md section 2.
-module(mqtt_avatar_family_text).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(_C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() -> {ok, Base} end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, Ctx) ->
    mqtt_avatar_part:payload_service(E, Ctx, <<"SetText">>, <<"Text">>, any).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].
