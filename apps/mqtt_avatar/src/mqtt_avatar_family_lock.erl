%% @doc Internal. The `lock' family (HA `lock', zigbee2mqtt's `lock'
%% expose): Lock, Unlock and OpenLock (when `payload_open' is set); the
%% stream LockState (locked, unlocked, locking, unlocking, jammed, open,
%% opening); ReadLock. docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_lock).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, from_z2m/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() ->
    [{<<"pl_lock">>, <<"payload_lock">>}, {<<"pl_unlk">>, <<"payload_unlock">>},
     {<<"pl_open">>, <<"payload_open">>}, {<<"stat_locked">>, <<"state_locked">>},
     {<<"stat_unlocked">>, <<"state_unlocked">>}, {<<"stat_locking">>, <<"state_locking">>},
     {<<"stat_unlocking">>, <<"state_unlocking">>}, {<<"stat_jam">>, <<"state_jammed">>},
     {<<"stat_open">>, <<"state_open">>}, {<<"stat_opening">>, <<"state_opening">>}].

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    Str = fun(K, D) -> mqtt_avatar_ha:str(K, C, D) end,
    mqtt_avatar_ha:command_and_state(C, Base, fun(T) ->
        {ok, Base#{topics => T,
                   payloads => #{lock => Str(<<"payload_lock">>, <<"LOCK">>),
                                 unlock => Str(<<"payload_unlock">>, <<"UNLOCK">>),
                                 open => Str(<<"payload_open">>, undefined)},
                   states => states(Str)}}
    end).

states(Str) ->
    [{Str(<<"state_locked">>, <<"LOCKED">>), <<"locked">>},
     {Str(<<"state_unlocked">>, <<"UNLOCKED">>), <<"unlocked">>},
     {Str(<<"state_locking">>, <<"LOCKING">>), <<"locking">>},
     {Str(<<"state_unlocking">>, <<"UNLOCKING">>), <<"unlocking">>},
     {Str(<<"state_jammed">>, <<"JAMMED">>), <<"jammed">>},
     {Str(<<"state_open">>, <<"OPEN">>), <<"open">>},
     {Str(<<"state_opening">>, <<"OPENING">>), <<"opening">>}].

%% @doc The entity of a zigbee2mqtt `lock' expose (feature `state' with
%% value_on LOCK, value_off UNLOCK).
-spec from_z2m(map(), mqtt_avatar_z2m:ctx()) -> [mqtt_avatar_discovery:entity()].
from_z2m(#{<<"features">> := Features}, Ctx) when is_list(Features) ->
    case [F || #{<<"name">> := <<"state">>, <<"property">> := P} = F <- Features, is_binary(P)] of
        [State | _] ->
            case mqtt_avatar_z2m:setting(State, <<"State">>, <<>>, Ctx) of
                [#{control := Cmd} = S] ->
                    Lock = mqtt_avatar_z2m:text(maps:get(<<"value_on">>, State, <<"LOCK">>)),
                    Unlock = mqtt_avatar_z2m:text(maps:get(<<"value_off">>, State, <<"UNLOCK">>)),
                    [(mqtt_avatar_z2m:entity(lock, <<"lock">>, Ctx))#{
                        topics => maps:merge(#{command => Cmd},
                                             maps:with([state], S)),
                        payloads => #{lock => Lock, unlock => Unlock, open => undefined},
                        states => [{Lock, <<"locked">>}, {Unlock, <<"unlocked">>}]}];
                _ -> []
            end;
        [] -> []
    end;
from_z2m(_, _Ctx) ->
    [].

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{topics := T, payloads := Pl, states := States} = E, Ctx) ->
    Caps = [{<<"Lock">>, <<"yes">>}],
    Read = [{<<"State">>, S, mqtt_avatar_part:map_text(States)} || {ok, S} <- [maps:find(state, T)]],
    %% Locking takes time: the command is done when the lock says
    %% locked (unlocked, open), not at `locking'.
    Echo = fun(Final) ->
                   case Read of
                       [{P, S, M}] -> {P, S, M, device_state(Final, States)};
                       [] -> undefined
                   end
           end,
    Services = [mqtt_avatar_part:fixed(Type, Caps, maps:get(command, T), Payload, Echo(Final), Ctx)
                || {Type, Key, Final} <- [{<<"Lock">>, lock, <<"locked">>},
                                          {<<"Unlock">>, unlock, <<"unlocked">>},
                                          {<<"OpenLock">>, open, <<"open">>}],
                   Payload <- [maps:get(Key, Pl)], is_binary(Payload)],
    mqtt_avatar_part:family(<<"Lock">>, Services, Read, E, Ctx).

device_state(Neutral, States) ->
    {Device, _} = lists:keyfind(Neutral, 2, States),
    Device.
