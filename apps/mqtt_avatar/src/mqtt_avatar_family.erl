%% @doc Internal. The device families an MQTT Avatar understands, one module
%% each (`mqtt_avatar_family_<HA component>'), and the dispatcher to them.
%% A family reads its Home Assistant discovery keys into a neutral entity
%% (`from_ha/2'), and writes that entity as BIL services and streams with
%% the reserved `Mqtt*' parameters (`generate/2'): those parameters say
%% what a request publishes and how a state payload becomes BIL
%% parameters, which mqtt_avatar_spec and mqtt_avatar_logic then run for
%% every family alike. zigbee2mqtt exposes become the same entities
%% (mqtt_avatar_z2m). docs/mqtt.md section 2 lists each family's BIL.
-module(mqtt_avatar_family).

-export([components/0, module/1, from_ha/3, generate/2, abbreviations/1]).

%% The HA config (keys expanded, `~' applied) and the entity the shared
%% keys give (uid, kind, name, device_class, state_topic, command_topic,
%% value, attributes, unit...); the family adds its own keys, or says
%% what is wrong.
-callback from_ha(Config :: map(), Base :: mqtt_avatar_discovery:entity()) ->
    {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
%% The entity's Services and Consumes entries.
-callback generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) ->
    mqtt_avatar_part:part().

%% HA's key abbreviations used only by this family (`[{Short, Full}]');
%% the shared ones are mqtt_avatar_ha's.
-callback abbreviations() -> [{binary(), binary()}].

%% HA component name, entity kind, module. Kinds are atoms of this list
%% only: a component name from the network is looked up here, never made
%% an atom.
-define(FAMILIES,
        [{<<"light">>, light, mqtt_avatar_family_light},
         {<<"switch">>, switch, mqtt_avatar_family_switch},
         {<<"binary_sensor">>, binary_sensor, mqtt_avatar_family_binary_sensor},
         {<<"sensor">>, sensor, mqtt_avatar_family_sensor},
         {<<"button">>, button, mqtt_avatar_family_button},
         {<<"text">>, text, mqtt_avatar_family_text},
         {<<"event">>, event, mqtt_avatar_family_event},
         {<<"siren">>, siren, mqtt_avatar_family_siren},
         {<<"notify">>, notify, mqtt_avatar_family_notify},
         {<<"cover">>, cover, mqtt_avatar_family_cover},
         {<<"valve">>, valve, mqtt_avatar_family_valve},
         {<<"climate">>, climate, mqtt_avatar_family_climate},
         {<<"fan">>, fan, mqtt_avatar_family_fan},
         {<<"humidifier">>, humidifier, mqtt_avatar_family_humidifier},
         {<<"lock">>, lock, mqtt_avatar_family_lock},
         {<<"number">>, number, mqtt_avatar_family_number},
         {<<"select">>, select, mqtt_avatar_family_select},
         {<<"alarm_control_panel">>, alarm_control_panel, mqtt_avatar_family_alarm_control_panel},
         {<<"scene">>, scene, mqtt_avatar_family_scene},
         {<<"vacuum">>, vacuum, mqtt_avatar_family_vacuum}]).

%% @doc The HA components understood.
-spec components() -> [binary()].
components() -> [C || {C, _, _} <- ?FAMILIES].

%% @doc The kind and module of an HA component, `error' for one not
%% understood.
-spec module(binary()) -> {ok, mqtt_avatar_discovery:kind(), module()} | error.
module(Component) ->
    case lists:keyfind(Component, 1, ?FAMILIES) of
        {_, Kind, Mod} -> {ok, Kind, Mod};
        false -> error
    end.

%% @doc The entity of an HA config of component `Component'.
-spec from_ha(binary(), map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(Component, Config, Base) ->
    {ok, _Kind, Mod} = module(Component),
    Mod:from_ha(Config, Base).

%% @doc The abbreviations of an HA component's family.
-spec abbreviations(binary()) -> [{binary(), binary()}].
abbreviations(Component) ->
    {ok, _Kind, Mod} = module(Component),
    Mod:abbreviations().

%% @doc The BIL of one entity, by its family.
-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{kind := Kind} = E, Ctx) ->
    {_, _, Mod} = lists:keyfind(Kind, 2, ?FAMILIES),
    Mod:generate(E, Ctx).
