%% @doc Internal. The `siren' family (HA `siren'): one service that turns
%% the siren on with a tone (`Sound'), and `Volume'/`Duration' when the
%% siren supports them, as JSON. zigbee2mqtt's sirens: the `warning'
%% composite (`StartWarning' with `Mode', `Level', `Strobe', `Duration';
%% `StopWarning'), `squawk' (`Squawk' with `State', `Level', `Strobe') and
%% a settable binary `alarm' (`TurnSirenOn', `TurnSirenOff'). docs/mqtt.md
%% sections 2.2 and 2.4.
-module(mqtt_avatar_family_siren).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, from_z2m/2, generate/2, abbreviations/0]).

%% A z2m composite's features that become request parameters, in order.
-define(WARNING_ARGS, [{<<"mode">>, <<"Mode">>}, {<<"level">>, <<"Level">>},
                       {<<"strobe">>, <<"Strobe">>}, {<<"duration">>, <<"Duration">>}]).
-define(SQUAWK_ARGS, [{<<"state">>, <<"State">>}, {<<"level">>, <<"Level">>},
                      {<<"strobe">>, <<"Strobe">>}]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        {ok, maps:merge(Base#{volume => mqtt_avatar_ha:bool(<<"support_volume_set">>, C, false),
                              duration => mqtt_avatar_ha:bool(<<"support_duration">>, C, false)},
                        mqtt_avatar_ha:on_off(C))}
    end).

%% @doc A zigbee2mqtt siren expose: a `warning' or `squawk' composite, or
%% a binary `alarm' that can be set. `[]' for anything else.
-spec from_z2m(map(), mqtt_avatar_z2m:ctx()) -> [mqtt_avatar_discovery:entity()].
from_z2m(#{<<"type">> := <<"composite">>, <<"property">> := P, <<"features">> := Fs}, Ctx)
  when (P =:= <<"warning">> orelse P =:= <<"squawk">>), is_list(Fs) ->
    Known = case P of
                <<"warning">> -> ?WARNING_ARGS;
                <<"squawk">> -> ?SQUAWK_ARGS
            end,
    Args = [{Param, <<P/binary, ".", F/binary>>, feature_check(X)}
            || {F, Param} <- Known,
               X <- [X || #{<<"property">> := FP} = X <- Fs, FP =:= F]],
    E = mqtt_avatar_z2m:entity(siren, P, Ctx),
    [E#{name := P, z2m => binary_to_z2m(P), args => Args,
        stop => lists:member(<<"stop">>, values(<<"mode">>, Fs))}];
from_z2m(#{<<"type">> := <<"binary">>, <<"property">> := <<"alarm">>} = X, Ctx) ->
    E = mqtt_avatar_z2m:entity(siren, <<"alarm_siren">>, Ctx),
    [E#{name := <<"siren">>, z2m => alarm,
        on => maps:get(<<"value_on">>, X, true), off => maps:get(<<"value_off">>, X, false)}];
from_z2m(_, _) ->
    [].

binary_to_z2m(<<"warning">>) -> warning;
binary_to_z2m(<<"squawk">>) -> squawk.

values(Property, Fs) ->
    case [Vs || #{<<"property">> := P, <<"values">> := Vs} <- Fs, P =:= Property, is_list(Vs)] of
        [Vs | _] -> [V || V <- [mqtt_avatar_z2m:text(V0) || V0 <- Vs], is_binary(V)];
        [] -> []
    end.

%% What a value of the feature must be (MqttArgCheck): one of an enum's
%% values, true or false for a binary, a numeric's range.
feature_check(#{<<"type">> := <<"enum">>, <<"values">> := Vs}) when is_list(Vs) ->
    mqtt_avatar_part:one_of([V || V <- [mqtt_avatar_z2m:text(V0) || V0 <- Vs], is_binary(V)]);
feature_check(#{<<"type">> := <<"binary">>}) ->
    <<"true|false">>;
feature_check(#{<<"type">> := <<"numeric">>, <<"value_min">> := Lo, <<"value_max">> := Hi})
  when is_number(Lo), is_number(Hi), Lo =< Hi ->
    <<(mqtt_avatar_z2m:text(Lo))/binary, "..", (mqtt_avatar_z2m:text(Hi))/binary>>;
feature_check(_) ->
    <<>>.

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{z2m := alarm} = E, Ctx) ->
    Json = fun(V) -> iolist_to_binary(["json:", evatar_json:encode(#{<<"alarm">> => V})]) end,
    Entry = fun(Type, V) ->
                    mqtt_avatar_part:entry(<<"ACTUATOR">>, Type,
                                           maps:get(room, Ctx)
                                           ++ [{<<"MqttCommandTopic">>, maps:get(command_topic, E)},
                                               {<<"MqttCommand">>, Json(V)},
                                               {<<"MqttExpect">>, <<"none">>}])
            end,
    mqtt_avatar_part:actuator([Entry(<<"TurnSirenOn">>, maps:get(on, E)),
                               Entry(<<"TurnSirenOff">>, maps:get(off, E))], Ctx);
generate(#{z2m := Kind, args := Args} = E, Ctx) ->
    Field = atom_to_binary(Kind),
    Type = case Kind of
               warning -> <<"StartWarning">>;
               squawk -> <<"Squawk">>
           end,
    Checks = [case Check of
                  <<>> -> Param;
                  _ -> <<Param/binary, "=", Check/binary>>
              end || {Param, _, Check} <- Args],
    Start = mqtt_avatar_part:entry(
              <<"ACTUATOR">>, Type,
              [{Param, <<"yes">>} || {Param, _, _} <- Args] ++ maps:get(room, Ctx)
              ++ [{<<"MqttCommandTopic">>, maps:get(command_topic, E)},
                  {<<"MqttCommand">>, <<"json:{\"", Field/binary, "\":{}}">>}]
              ++ [{<<"MqttCommandArgs">>,
                   iolist_to_binary(lists:join(" ", [<<Param/binary, "=", Path/binary>>
                                                     || {Param, Path, _} <- Args]))}
                  || Args =/= []]
              ++ [{<<"MqttArgCheck">>, iolist_to_binary(lists:join(" ", Checks))} || Checks =/= []]
              ++ [{<<"MqttExpect">>, <<"none">>}]),
    %% The warning is set-only: zigbee2mqtt publishes no state for it.
    Stop = [mqtt_avatar_part:entry(<<"ACTUATOR">>, <<"StopWarning">>,
                                   maps:get(room, Ctx)
                                   ++ [{<<"MqttCommandTopic">>, maps:get(command_topic, E)},
                                       {<<"MqttCommand">>, <<"json:{\"warning\":{\"mode\":\"stop\"}}">>},
                                       {<<"MqttExpect">>, <<"none">>}])
            || Kind =:= warning, maps:get(stop, E, true)],
    mqtt_avatar_part:actuator([Start | Stop], Ctx);
generate(E, Ctx) ->
    Type = mqtt_avatar_part:camel(mqtt_avatar_part:first_name([maps:get(name, E), <<"PlaySound">>])),
    Args = [<<"Sound=tone">>]
        ++ [<<"Volume=volume_level">> || maps:get(volume, E)]
        ++ [<<"Duration=duration">> || maps:get(duration, E)],
    Capabilities = [{<<"Sound">>, <<"yes">>}]
        ++ [{<<"Volume">>, <<"yes">>} || maps:get(volume, E)]
        ++ [{<<"Duration">>, <<"yes">>} || maps:get(duration, E)],
    Command = evatar_json:encode(#{<<"state">> => maps:get(on, E)}),
    Params = Capabilities ++ maps:get(room, Ctx)
        ++ [{<<"MqttCommandTopic">>, maps:get(command_topic, E)},
            {<<"MqttCommand">>, <<"json:", Command/binary>>},
            {<<"MqttCommandArgs">>, iolist_to_binary(lists:join(" ", Args))}]
        ++ mqtt_avatar_part:echo_params(E, <<"any">>),
    mqtt_avatar_part:actuator([mqtt_avatar_part:entry(<<"ACTUATOR">>, Type, Params)], Ctx).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].
