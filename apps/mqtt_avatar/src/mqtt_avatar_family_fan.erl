%% @doc Internal. The `fan' family (HA `fan', zigbee2mqtt's `fan' expose):
%% TurnFanOn/TurnFanOff, SetFanPercentage, SetFanPresetMode,
%% StartFanOscillation/StopFanOscillation, SetFanDirection; streams
%% FanState, FanPercentage, FanPresetMode, FanOscillation, FanDirection;
%% ReadFan. docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_fan).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, from_z2m/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() ->
    [{<<"pct_cmd_t">>, <<"percentage_command_topic">>},
     {<<"pct_stat_t">>, <<"percentage_state_topic">>},
     {<<"pct_val_tpl">>, <<"percentage_value_template">>},
     {<<"pr_mode_cmd_t">>, <<"preset_mode_command_topic">>},
     {<<"pr_mode_stat_t">>, <<"preset_mode_state_topic">>},
     {<<"pr_mode_val_tpl">>, <<"preset_mode_value_template">>},
     {<<"pr_modes">>, <<"preset_modes">>},
     {<<"osc_cmd_t">>, <<"oscillation_command_topic">>},
     {<<"osc_stat_t">>, <<"oscillation_state_topic">>},
     {<<"osc_val_tpl">>, <<"oscillation_value_template">>},
     {<<"pl_osc_on">>, <<"payload_oscillation_on">>}, {<<"pl_osc_off">>, <<"payload_oscillation_off">>},
     {<<"dir_cmd_t">>, <<"direction_command_topic">>}, {<<"dir_stat_t">>, <<"direction_state_topic">>},
     {<<"dir_val_tpl">>, <<"direction_value_template">>},
     {<<"spd_rng_min">>, <<"speed_range_min">>}, {<<"spd_rng_max">>, <<"speed_range_max">>},
     {<<"pct_cmd_tpl">>, <<"percentage_command_template">>},
     {<<"pr_mode_cmd_tpl">>, <<"preset_mode_command_template">>},
     {<<"osc_cmd_tpl">>, <<"oscillation_command_template">>},
     {<<"dir_cmd_tpl">>, <<"direction_command_template">>}].

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    Str = fun(K, D) -> mqtt_avatar_ha:str(K, C, D) end,
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        Specs = [{<<"Percentage">>, <<"SetFanPercentage">>, <<"percentage_command_topic">>,
                  <<"percentage_state_topic">>, <<"percentage_value_template">>,
                  <<"0..100">>},
                 {<<"PresetMode">>, <<"SetFanPresetMode">>, <<"preset_mode_command_topic">>,
                  <<"preset_mode_state_topic">>, <<"preset_mode_value_template">>,
                  mqtt_avatar_part:one_of(mqtt_avatar_ha:strings(<<"preset_modes">>, C))},
                 {<<"Direction">>, <<"SetFanDirection">>, <<"direction_command_topic">>,
                  <<"direction_state_topic">>, <<"direction_value_template">>,
                  <<"forward|reverse">>}],
        OscOn = Str(<<"payload_oscillation_on">>, <<"oscillate_on">>),
        OscOff = Str(<<"payload_oscillation_off">>, <<"oscillate_off">>),
        case {mqtt_avatar_ha:settings(C, Specs),
              mqtt_avatar_ha:settings(C, [{<<"Oscillation">>, <<>>, <<"oscillation_command_topic">>,
                                           <<"oscillation_state_topic">>,
                                           <<"oscillation_value_template">>, <<>>}])} of
            {{ok, Settings0}, {ok, Osc}} ->
                Settings = [speed_range(C, S) || S <- Settings0],
                {ok, maps:merge(Base#{json_command => false, settings => Settings,
                                      oscillation => [O#{map => mqtt_avatar_part:map_text(
                                                                  [{OscOn, <<"yes">>},
                                                                   {OscOff, <<"no">>}]),
                                                         on => OscOn, off => OscOff} || O <- Osc]},
                                mqtt_avatar_ha:on_off(C))};
            {{error, _} = E, _} -> E;
            {_, {error, _} = E} -> E
        end
    end).

%% HA's speed_range_min..speed_range_max (default 1..100): the VA's
%% Percentage 0..100 is scaled to it on the wire, and back (MqttScale).
speed_range(C, #{param := <<"Percentage">>} = S) ->
    Lo = integer_key(<<"speed_range_min">>, C, 1),
    Hi = integer_key(<<"speed_range_max">>, C, 100),
    case {Lo, Hi} of
        {1, 100} -> S;
        _ when Lo >= 1, Lo =< Hi ->
            Range = iolist_to_binary([integer_to_binary(Lo), "..", integer_to_binary(Hi)]),
            maps:map(fun(K, V) when K =:= control; K =:= state -> V#{scale => Range};
                        (_, V) -> V
                     end, S);
        _ -> S
    end;
speed_range(_C, S) ->
    S.

integer_key(Key, C, Default) ->
    case maps:get(Key, C, Default) of
        N when is_integer(N), N >= 0, N < 1000000 -> N;
        _ -> Default
    end.

%% @doc The entity of a zigbee2mqtt `fan' expose (features `state' and
%% `mode').
-spec from_z2m(map(), mqtt_avatar_z2m:ctx()) -> [mqtt_avatar_discovery:entity()].
from_z2m(#{<<"features">> := Features}, Ctx) when is_list(Features) ->
    case [F || #{<<"name">> := <<"state">>, <<"property">> := P} = F <- Features, is_binary(P)] of
        [#{<<"property">> := P} = State | _] ->
            On = mqtt_avatar_z2m:text(maps:get(<<"value_on">>, State, null), <<"ON">>),
            Off = mqtt_avatar_z2m:text(maps:get(<<"value_off">>, State, null), <<"OFF">>),
            Modes = lists:append([mqtt_avatar_z2m:setting(F, <<"PresetMode">>, <<"SetFanPresetMode">>, Ctx)
                                  || #{<<"name">> := <<"mode">>} = F <- Features]),
            E = mqtt_avatar_z2m:entity(fan, P, Ctx),
            [E#{value := {json, [P]}, json_command => true, on => On, off => Off, state_on => On,
                state_off => Off, settings => Modes, oscillation => []}];
        [] ->
            []
    end;
from_z2m(_, _Ctx) ->
    [].

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{settings := Settings, oscillation := Osc} = E, Ctx) ->
    Caps = [{<<"Fan">>, <<"yes">>}],
    #{services := OnOff} = mqtt_avatar_part:on_off(E, Ctx, {<<"TurnFanOn">>, <<"TurnFanOff">>}, Caps,
                                                   <<"State">>, <<"Fan">>),
    {Services, Reads} = mqtt_avatar_part:settings(Settings, Caps, Ctx),
    OscReads = [{<<"Oscillation">>, S, M} || #{state := S, map := M} <- Osc],
    Oscillate = [mqtt_avatar_part:fixed(Type, Caps, Control, Payload,
                                        mqtt_avatar_part:echo_of(<<"Oscillation">>, OscReads), Ctx)
                 || #{control := Control, on := On, off := Off} <- Osc,
                    {Type, Payload} <- [{<<"StartFanOscillation">>, On},
                                        {<<"StopFanOscillation">>, Off}]],
    State = case maps:get(state_topic, E) of
                undefined -> [];
                T -> [{<<"State">>, #{topic => T, source => maps:get(value, E)},
                       mqtt_avatar_part:on_off_map(E, <<"on">>, <<"off">>)}]
            end,
    mqtt_avatar_part:family(<<"Fan">>, OnOff ++ Services ++ Oscillate, State ++ Reads ++ OscReads,
                            E, Ctx).
