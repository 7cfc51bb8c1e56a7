%% @doc Internal. The `cover' family (HA `cover', zigbee2mqtt's `cover'
%% expose): blinds, shutters, curtains, garage doors. OpenCover, CloseCover,
%% StopCover, SetCoverPosition and SetCoverTilt; streams CoverState,
%% CoverPosition, CoverTilt; ReadCover. docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_cover).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, from_z2m/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() ->
    [{<<"pos_t">>, <<"position_topic">>}, {<<"pos_tpl">>, <<"position_template">>},
     {<<"set_pos_t">>, <<"set_position_topic">>}, {<<"set_pos_tpl">>, <<"set_position_template">>},
     {<<"pos_open">>, <<"position_open">>}, {<<"pos_clsd">>, <<"position_closed">>},
     {<<"pl_open">>, <<"payload_open">>}, {<<"pl_cls">>, <<"payload_close">>},
     {<<"pl_stop">>, <<"payload_stop">>}, {<<"pl_stop_tilt">>, <<"payload_stop_tilt">>},
     {<<"stat_open">>, <<"state_open">>}, {<<"stat_opening">>, <<"state_opening">>},
     {<<"stat_clsd">>, <<"state_closed">>}, {<<"stat_closing">>, <<"state_closing">>},
     {<<"stat_stopped">>, <<"state_stopped">>},
     {<<"tilt_cmd_t">>, <<"tilt_command_topic">>}, {<<"tilt_cmd_tpl">>, <<"tilt_command_template">>},
     {<<"tilt_status_t">>, <<"tilt_status_topic">>},
     {<<"tilt_status_tpl">>, <<"tilt_status_template">>},
     {<<"tilt_min">>, <<"tilt_min">>}, {<<"tilt_max">>, <<"tilt_max">>}].

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    Str = fun(K, D) -> mqtt_avatar_ha:str(K, C, D) end,
    case mqtt_avatar_ha:read(C, [{command, {control, <<"command_topic">>}},
                                 {state, {state, <<"state_topic">>, <<"value_template">>}},
                                 {set_position, {control, <<"set_position_topic">>}},
                                 {position, {state, <<"position_topic">>, <<"position_template">>}},
                                 {set_tilt, {control, <<"tilt_command_topic">>}},
                                 {tilt, {state, <<"tilt_status_topic">>, <<"tilt_status_template">>}}]) of
        {ok, T} when map_size(T) =:= 0 ->
            {error, <<"a cover needs command_topic, set_position_topic or tilt_command_topic">>};
        {ok, T} ->
            {ok, Base#{topics => T,
                       payloads => #{open => Str(<<"payload_open">>, <<"OPEN">>),
                                     close => Str(<<"payload_close">>, <<"CLOSE">>),
                                     stop => Str(<<"payload_stop">>, <<"STOP">>)},
                       states => [{Str(<<"state_open">>, <<"open">>), <<"open">>},
                                  {Str(<<"state_opening">>, <<"opening">>), <<"opening">>},
                                  {Str(<<"state_closed">>, <<"closed">>), <<"closed">>},
                                  {Str(<<"state_closing">>, <<"closing">>), <<"closing">>},
                                  {Str(<<"state_stopped">>, <<"stopped">>), <<"stopped">>}],
                       range => {mqtt_avatar_ha:number(<<"position_closed">>, C, <<"0">>),
                                 mqtt_avatar_ha:number(<<"position_open">>, C, <<"100">>)},
                       tilt_range => {mqtt_avatar_ha:number(<<"tilt_min">>, C, <<"0">>),
                                      mqtt_avatar_ha:number(<<"tilt_max">>, C, <<"100">>)}}};
        {error, _} = E ->
            E
    end.

%% @doc The entity of a zigbee2mqtt `cover' expose (features `state' with
%% OPEN/CLOSE/STOP, `position', `tilt').
-spec from_z2m(map(), mqtt_avatar_z2m:ctx()) -> [mqtt_avatar_discovery:entity()].
from_z2m(#{<<"features">> := Features}, Ctx) when is_list(Features) ->
    Named = fun(Name) -> [F || #{<<"name">> := N, <<"property">> := P} = F <- Features,
                               N =:= Name, is_binary(P)]
            end,
    Setting = fun(Name, Param) -> lists:append([mqtt_avatar_z2m:setting(F, Param, <<>>, Ctx)
                                                || F <- Named(Name)])
              end,
    T0 = case Setting(<<"state">>, <<"State">>) of
             [#{control := Cmd} = St | _] -> #{command => Cmd, state => maps:get(state, St, undefined)};
             [St | _] -> #{state => maps:get(state, St, undefined)};
             [] -> #{}
         end,
    T1 = lists:foldl(fun({Name, SetKey, ReadKey}, Acc) ->
                             case Setting(Name, Name) of
                                 [S | _] ->
                                     maps:merge(Acc, maps:from_list(
                                                       [{SetKey, V} || {ok, V} <- [maps:find(control, S)]]
                                                       ++ [{ReadKey, V} || {ok, V} <- [maps:find(state, S)]]));
                                 [] -> Acc
                             end
                     end, T0, [{<<"position">>, set_position, position}, {<<"tilt">>, set_tilt, tilt}]),
    T = maps:filter(fun(_, V) -> V =/= undefined end, T1),
    case map_size(T) of
        0 -> [];
        _ -> [(mqtt_avatar_z2m:entity(cover, <<"cover">>, Ctx))#{
                 topics => T,
                 payloads => #{open => <<"OPEN">>, close => <<"CLOSE">>, stop => <<"STOP">>},
                 states => [{<<"OPEN">>, <<"open">>}, {<<"CLOSE">>, <<"closed">>}],
                 range => {<<"0">>, <<"100">>}, tilt_range => {<<"0">>, <<"100">>}}]
    end;
from_z2m(_, _Ctx) ->
    [].

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{topics := T, payloads := Pl, states := States} = E, Ctx) ->
    Caps = [{<<"Cover">>, <<"yes">>}]
        ++ [{<<"DeviceClass">>, C} || C <- [maps:get(device_class, E)], is_binary(C)],
    Map = mqtt_avatar_part:map_text(States),
    Read = [{<<"State">>, maps:get(state, T), Map} || is_map_key(state, T)]
        ++ [{<<"Position">>, maps:get(position, T), <<>>} || is_map_key(position, T)]
        ++ [{<<"Tilt">>, maps:get(tilt, T), <<>>} || is_map_key(tilt, T)],
    Echo = fun(Param) -> mqtt_avatar_part:echo_of(Param, Read) end,
    MoveEcho = case {Echo(<<"State">>), Echo(<<"Position">>)} of
                   {undefined, P} -> P;
                   {S, _} -> S
               end,
    Fixed = [mqtt_avatar_part:fixed(Type, Caps, maps:get(command, T), maps:get(Key, Pl), MoveEcho, Ctx)
             || is_map_key(command, T),
                {Type, Key} <- [{<<"OpenCover">>, open}, {<<"CloseCover">>, close},
                                {<<"StopCover">>, stop}]],
    Range = fun({Lo, Hi}) -> mqtt_avatar_part:range(Lo, Hi) end,
    Position = [mqtt_avatar_part:setter(<<"SetCoverPosition">>, <<"Position">>, Caps,
                                        maps:get(set_position, T), Range(maps:get(range, E)),
                                        Echo(<<"Position">>), Ctx)
                || is_map_key(set_position, T)],
    Tilt = [mqtt_avatar_part:setter(<<"SetCoverTilt">>, <<"Tilt">>, Caps, maps:get(set_tilt, T),
                                    Range(maps:get(tilt_range, E)), Echo(<<"Tilt">>), Ctx)
            || is_map_key(set_tilt, T)],
    mqtt_avatar_part:family(<<"Cover">>, Fixed ++ Position ++ Tilt, Read, E, Ctx).
