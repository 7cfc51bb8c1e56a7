%% @doc Internal. The `alarm_control_panel' family (HA
%% `alarm_control_panel'): ArmAway, ArmHome, ArmNight, ArmVacation,
%% ArmCustomBypass, Disarm, TriggerAlarm (as `supported_features' says);
%% the stream AlarmState and ReadAlarm. A panel with a local `code' needs
%% the request parameter `Code', checked by the Avatar against a
%% PBKDF2 hash of it (MqttCode) and never published, logged or echoed;
%% a remote code (`REMOTE_CODE') must be present and goes to the device
%% through the panel's `command_template' (`code'). docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_alarm_control_panel).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() ->
    [{<<"pl_arm_away">>, <<"payload_arm_away">>}, {<<"pl_arm_home">>, <<"payload_arm_home">>},
     {<<"pl_arm_nite">>, <<"payload_arm_night">>}, {<<"pl_arm_vacation">>, <<"payload_arm_vacation">>},
     {<<"pl_arm_custom_b">>, <<"payload_arm_custom_bypass">>},
     {<<"pl_disarm">>, <<"payload_disarm">>}, {<<"pl_trig">>, <<"payload_trigger">>},
     {<<"cod_arm_req">>, <<"code_arm_required">>}, {<<"cod_dis_req">>, <<"code_disarm_required">>},
     {<<"cod_trig_req">>, <<"code_trigger_required">>}, {<<"sup_feat">>, <<"supported_features">>}].

%% Iterations of the code's hash: slow enough to make guessing from the
%% description cost something, fast enough per request.
-define(ITERATIONS, 20000).

%% Feature, service, payload key and default, the state it ends in, and
%% which `code_*_required' applies.
-define(ACTIONS,
        [{<<"arm_away">>, <<"ArmAway">>, <<"payload_arm_away">>, <<"ARM_AWAY">>, <<"armed_away">>, arm},
         {<<"arm_home">>, <<"ArmHome">>, <<"payload_arm_home">>, <<"ARM_HOME">>, <<"armed_home">>, arm},
         {<<"arm_night">>, <<"ArmNight">>, <<"payload_arm_night">>, <<"ARM_NIGHT">>, <<"armed_night">>,
          arm},
         {<<"arm_vacation">>, <<"ArmVacation">>, <<"payload_arm_vacation">>, <<"ARM_VACATION">>,
          <<"armed_vacation">>, arm},
         {<<"arm_custom_bypass">>, <<"ArmCustomBypass">>, <<"payload_arm_custom_bypass">>,
          <<"ARM_CUSTOM_BYPASS">>, <<"armed_custom_bypass">>, arm},
         {disarm, <<"Disarm">>, <<"payload_disarm">>, <<"DISARM">>, <<"disarmed">>, disarm},
         {<<"trigger">>, <<"TriggerAlarm">>, <<"payload_trigger">>, <<"TRIGGER">>, <<"triggered">>,
          trigger}]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        Features = case mqtt_avatar_ha:strings(<<"supported_features">>, C) of
                       undefined -> [F || {F, _, _, _, _, _} <- ?ACTIONS, is_binary(F)];
                       L -> L
                   end,
        Code = case maps:get(<<"code">>, C, undefined) of
                   <<"REMOTE_CODE">> -> remote;
                   <<"REMOTE_CODE_TEXT">> -> remote;
                   Local when is_binary(Local), Local =/= <<>> -> {local, hash(Local, maps:get(uid, Base))};
                   Local when is_integer(Local) -> {local, hash(integer_to_binary(Local),
                                                                maps:get(uid, Base))};
                   _ -> none
               end,
        Required = #{arm => mqtt_avatar_ha:bool(<<"code_arm_required">>, C, true),
                     disarm => mqtt_avatar_ha:bool(<<"code_disarm_required">>, C, true),
                     trigger => mqtt_avatar_ha:bool(<<"code_trigger_required">>, C, true)},
        Actions = [{Type, mqtt_avatar_ha:str(Key, C, Default), Final,
                    Code =/= none andalso maps:get(Need, Required)}
                   || {Feature, Type, Key, Default, Final, Need} <- ?ACTIONS,
                      Feature =:= disarm orelse lists:member(Feature, Features)],
        case mqtt_avatar_ha:command_template(mqtt_avatar_ha:str(<<"command_template">>, C)) of
            {ok, Tpl} -> {ok, Base#{actions => Actions, code => Code, template => Tpl}};
            {error, _} = Error -> Error
        end
    end).

%% The description holds this, never the code.
hash(Code, Salt) ->
    Hash = crypto:pbkdf2_hmac(sha256, Code, Salt, ?ITERATIONS, 32),
    iolist_to_binary(["pbkdf2-sha256:", integer_to_list(?ITERATIONS), ":", binary:encode_hex(Salt),
                      ":", binary:encode_hex(Hash)]).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{actions := Actions, code := Code, command_topic := Topic} = E, Ctx) ->
    Read = case maps:get(state_topic, E) of
               undefined -> [];
               T -> [{<<"State">>, #{topic => T, source => maps:get(value, E)}, <<>>}]
           end,
    Services = [mqtt_avatar_part:fixed(
                  Type, [{<<"Alarm">>, <<"yes">>}] ++ code_params(Needs, Code)
                        ++ [{<<"MqttProgress">>, <<"raw:", P/binary>>} || Read =/= [],
                                                                          P <- progress(Final)],
                  maps:merge(#{topic => Topic, field => undefined},
                             maps:filter(fun(_, V) -> V =/= undefined end, maps:with([template], E))),
                  Payload,
                  case Read of
                      [{Pm, S, M}] -> {Pm, S, M, Final};
                      [] -> undefined
                  end, Ctx)
                || {Type, Payload, Final, Needs} <- Actions],
    mqtt_avatar_part:family(<<"Alarm">>, Services, Read, E, Ctx).

%% Arming and disarming pass through `arming'/`pending'/`disarming'.
progress(<<"disarmed">>) -> [<<"disarming">>];
progress(<<"triggered">>) -> [<<"pending">>];
progress(_) -> [<<"arming">>].

code_params(false, _) -> [];
code_params(true, {local, Hash}) -> [{<<"Code">>, <<"yes">>}, {<<"MqttCode">>, Hash}];
code_params(true, remote) -> [{<<"Code">>, <<"yes">>}, {<<"MqttArgCheck">>, <<"Code">>}].
