%% @doc Internal. The `valve' family (HA `valve'): water and gas valves.
%% OpenValve, CloseValve, StopValve (when `payload_stop' is set),
%% SetValvePosition (when it `reports_position'); streams ValveState or
%% ValvePosition; ReadValve. docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_valve).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() ->
    [{<<"pl_open">>, <<"payload_open">>}, {<<"pl_cls">>, <<"payload_close">>},
     {<<"pl_stop">>, <<"payload_stop">>}, {<<"pos">>, <<"reports_position">>},
     {<<"pos_open">>, <<"position_open">>}, {<<"pos_clsd">>, <<"position_closed">>},
     {<<"stat_open">>, <<"state_open">>}, {<<"stat_opening">>, <<"state_opening">>},
     {<<"stat_clsd">>, <<"state_closed">>}, {<<"stat_closing">>, <<"state_closing">>}].

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    Str = fun(K, D) -> mqtt_avatar_ha:str(K, C, D) end,
    mqtt_avatar_ha:command_and_state(C, Base, fun(T) ->
        {ok, Base#{topics => T,
                   reports_position => mqtt_avatar_ha:bool(<<"reports_position">>, C, false),
                   payloads => #{open => Str(<<"payload_open">>, <<"OPEN">>),
                                 close => Str(<<"payload_close">>, <<"CLOSE">>),
                                 stop => Str(<<"payload_stop">>, undefined)},
                   states => [{Str(<<"state_open">>, <<"open">>), <<"open">>},
                              {Str(<<"state_opening">>, <<"opening">>), <<"opening">>},
                              {Str(<<"state_closed">>, <<"closed">>), <<"closed">>},
                              {Str(<<"state_closing">>, <<"closing">>), <<"closing">>}],
                   range => {mqtt_avatar_ha:number(<<"position_closed">>, C, <<"0">>),
                             mqtt_avatar_ha:number(<<"position_open">>, C, <<"100">>)}}}
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{topics := T, payloads := Pl, states := States, reports_position := ByPosition} = E,
         Ctx) ->
    Caps = [{<<"Valve">>, <<"yes">>}]
        ++ [{<<"DeviceClass">>, C} || C <- [maps:get(device_class, E)], is_binary(C)],
    Read = case {ByPosition, maps:find(state, T)} of
               {_, error} -> [];
               {true, {ok, S}} -> [{<<"Position">>, S, <<>>}];
               {false, {ok, S}} -> [{<<"State">>, S, mqtt_avatar_part:map_text(States)}]
           end,
    Echo = case Read of
               [R] -> R;
               [] -> undefined
           end,
    Command = maps:get(command, T),
    Fixed = [mqtt_avatar_part:fixed(Type, Caps, Command, Payload, Echo, Ctx)
             || {Type, Key} <- [{<<"OpenValve">>, open}, {<<"CloseValve">>, close},
                                {<<"StopValve">>, stop}],
                Payload <- [maps:get(Key, Pl)], is_binary(Payload)],
    {Lo, Hi} = maps:get(range, E),
    Position = [mqtt_avatar_part:setter(<<"SetValvePosition">>, <<"Position">>, Caps, Command,
                                        mqtt_avatar_part:range(Lo, Hi), Echo, Ctx)
                || ByPosition],
    mqtt_avatar_part:family(<<"Valve">>, Fixed ++ Position, Read, E, Ctx).
