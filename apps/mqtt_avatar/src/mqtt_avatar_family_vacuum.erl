%% @doc Internal. The `vacuum' family (HA `vacuum', its JSON state
%% `{"state": ..., "battery_level": ..., "fan_speed": ...}'): StartVacuum,
%% PauseVacuum, StopVacuum, ReturnVacuumToBase, LocateVacuum, CleanSpot
%% (as `supported_features' says), SetVacuumFanSpeed, SendVacuumCommand;
%% streams VacuumState, VacuumBattery, VacuumFanSpeed; ReadVacuum.
%% docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_vacuum).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() ->
    [{<<"pl_strt">>, <<"payload_start">>}, {<<"pl_paus">>, <<"payload_pause">>},
     {<<"pl_stop">>, <<"payload_stop">>}, {<<"pl_ret">>, <<"payload_return_to_base">>},
     {<<"pl_loc">>, <<"payload_locate">>}, {<<"pl_cln_sp">>, <<"payload_clean_spot">>},
     {<<"set_fan_spd_t">>, <<"set_fan_speed_topic">>}, {<<"fanspd_lst">>, <<"fan_speed_list">>},
     {<<"send_cmd_t">>, <<"send_command_topic">>}, {<<"sup_feat">>, <<"supported_features">>}].

%% HA's default features of an MQTT vacuum.
-define(DEFAULT_FEATURES, [<<"start">>, <<"stop">>, <<"return_home">>, <<"status">>, <<"battery">>,
                           <<"clean_spot">>]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    Str = fun(K, D) -> mqtt_avatar_ha:str(K, C, D) end,
    Features = case mqtt_avatar_ha:strings(<<"supported_features">>, C) of
                   undefined -> ?DEFAULT_FEATURES;
                   L -> L
               end,
    Has = fun(F) -> lists:member(F, Features) end,
    case mqtt_avatar_ha:read(C, [{command, {control, <<"command_topic">>}},
                                 {fan_speed, {control, <<"set_fan_speed_topic">>}},
                                 {send, {control, <<"send_command_topic">>}}]) of
        {ok, T} when map_size(T) =:= 0 ->
            {error, <<"a vacuum needs command_topic, set_fan_speed_topic or send_command_topic">>};
        {ok, T} ->
            Payloads = [{Type, Str(Key, Default)}
                        || {Feature, Type, Key, Default} <-
                               [{<<"start">>, <<"StartVacuum">>, <<"payload_start">>, <<"start">>},
                                {<<"pause">>, <<"PauseVacuum">>, <<"payload_pause">>, <<"pause">>},
                                {<<"stop">>, <<"StopVacuum">>, <<"payload_stop">>, <<"stop">>},
                                {<<"return_home">>, <<"ReturnVacuumToBase">>,
                                 <<"payload_return_to_base">>, <<"return_to_base">>},
                                {<<"locate">>, <<"LocateVacuum">>, <<"payload_locate">>, <<"locate">>},
                                {<<"clean_spot">>, <<"CleanSpot">>, <<"payload_clean_spot">>,
                                 <<"clean_spot">>}],
                           Has(Feature)],
            States = case maps:get(state_topic, Base) of
                         undefined -> [];
                         ST -> [{P, #{topic => ST, source => {json, [Field]}}, <<>>}
                                || {Feature, P, Field} <- [{<<"status">>, <<"State">>, <<"state">>},
                                                           {<<"battery">>, <<"Battery">>,
                                                            <<"battery_level">>},
                                                           {<<"fan_speed">>, <<"FanSpeed">>,
                                                            <<"fan_speed">>}],
                                   Has(Feature) orelse Feature =:= <<"status">>]
                     end,
            {ok, Base#{topics => T, payloads => Payloads, states => States,
                       fan_speeds => mqtt_avatar_part:one_of(
                                       mqtt_avatar_ha:strings(<<"fan_speed_list">>, C))}};
        {error, _} = E ->
            E
    end.

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{topics := T, payloads := Payloads, states := States} = E, Ctx) ->
    Caps = [{<<"Vacuum">>, <<"yes">>}],
    Echo = mqtt_avatar_part:echo_of(<<"State">>, States),
    Fixed = [mqtt_avatar_part:fixed(Type, Caps, Command, Payload, Echo, Ctx)
             || {ok, Command} <- [maps:find(command, T)], {Type, Payload} <- Payloads],
    Speed = [mqtt_avatar_part:setter(<<"SetVacuumFanSpeed">>, <<"FanSpeed">>, Caps, Control,
                                     maps:get(fan_speeds, E),
                                     mqtt_avatar_part:echo_of(<<"FanSpeed">>, States), Ctx)
             || {ok, Control} <- [maps:find(fan_speed, T)]],
    Send = [mqtt_avatar_part:setter(<<"SendVacuumCommand">>, <<"Command">>, Caps, Control, <<>>,
                                    undefined, Ctx)
            || {ok, Control} <- [maps:find(send, T)]],
    mqtt_avatar_part:family(<<"Vacuum">>, Fixed ++ Speed ++ Send, States, E, Ctx).
