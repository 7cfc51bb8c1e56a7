%% @doc Internal. The HTTP binding of the exported Things (docs/wot.md):
%% the TD listing (`GET /api/things'), each Avatar's TD, its actions
%% (`POST .../actions/COMPONENT/SERVICE', a BIL request in the pairing
%% through the pairing's WoT consumer, evatar_web_thing) and properties
%% (`GET .../properties/COMPONENT/SERVICE', the stream's last reading), and
%% the node's own TD at `/.well-known/wot'.
-module(evatar_web_things).

-export([list/1, td/1, invoke/1, read/1, read_all/1, well_known/1]).

-define(TD_TYPE, "application/td+json").

%% @doc GET /api/things: every TD this node exports, as a JSON array.
-spec list(evatar_web_router:request()) -> evatar_web_router:reply().
list(Req) ->
    Base = base(Req),
    TDs = [evatar_web_td:thing(node(), P, D, Base, mqtt(D))
           || {P, Pid} <- evatar_web_things_sup:consumers(), D <- safe_things(Pid)],
    {raw, 200, [{"content-type", "application/json"}, {"cache-control", "no-store"}],
     evatar_json:encode(TDs)}.

%% @doc GET /api/things/{pairing}/{entity}: one TD.
-spec td(evatar_web_router:request()) -> evatar_web_router:reply().
td(Req) ->
    with_thing(Req, fun(P, _Pid, D) ->
                            td_reply(evatar_web_td:thing(node(), P, D, base(Req), mqtt(D)))
                    end).

%% An entity that is an MQTT Avatar this node keeps (by its entity id):
%% its broker and full description, for the MQTT forms of its devices.
mqtt(#{entity_id := Entity}) ->
    case [Pid || #{entity_id := E, avatar := Pid} <- mqtt_avatar:kept(), E =:= Entity, is_pid(Pid)] of
        [Pid] ->
            try
                #{broker := #{host := Host, port := Port}} = mqtt_avatar:status(Pid),
                #{host => host(Host), port => Port, description => mqtt_avatar:description(Pid)}
            catch
                %% Gone or restarting meanwhile: the TD has its HTTP forms.
                exit:_ -> none
            end;
        [] ->
            none
    end.

host(H) when is_tuple(H) -> list_to_binary(inet:ntoa(H));
host(H) -> unicode:characters_to_binary(H).

%% @doc POST /api/things/{pairing}/{entity}/actions/{component}/{service}.
-spec invoke(evatar_web_router:request()) -> evatar_web_router:reply().
invoke(#{bindings := #{<<"component">> := C, <<"service">> := S}, body := Body} = Req) ->
    with_thing(Req, fun(_P, Pid, #{entity_id := E}) ->
                            case input(Body) of
                                {ok, Params} -> answer(evatar_web_thing:invoke(Pid, E, C, S, Params));
                                {error, Why} -> {error, 400, <<"bad_request">>, <<"input">>, Why}
                            end
                    end).

%% @doc GET /api/things/{pairing}/{entity}/properties/{component}/{service}.
-spec read(evatar_web_router:request()) -> evatar_web_router:reply().
read(#{bindings := #{<<"component">> := C, <<"service">> := S}} = Req) ->
    with_thing(Req, fun(_P, Pid, #{entity_id := E}) ->
                            answer(evatar_web_thing:read(Pid, E, C, S))
                    end).

%% @doc GET /api/things/{pairing}/{entity}/properties: every property with
%% a reading, by its TD name.
-spec read_all(evatar_web_router:request()) -> evatar_web_router:reply().
read_all(Req) ->
    with_thing(Req, fun(_P, Pid, #{entity_id := E} = D) ->
                            {200, maps:from_list(
                                    [{N, params(Sig)}
                                     || #{kind := property, name := N, component := C,
                                          entry := #{type := T}} <- evatar_web_td:affordances(D),
                                        {ok, Sig} <- [evatar_web_thing:read(Pid, E, C, T)]])}
                    end).

%% @doc GET /.well-known/wot: the node's own TD, a directory of its Things.
-spec well_known(evatar_web_router:request()) -> evatar_web_router:reply().
well_known(Req) ->
    td_reply(evatar_web_td:directory(node(), base(Req))).

%% ---------------------------------------------------------------------------

with_thing(#{bindings := #{<<"pairing">> := P, <<"entity">> := E}}, Fun) ->
    case evatar_web_things_sup:consumer(P) of
        {ok, Pid} ->
            case [D || #{entity_id := En} = D <- safe_things(Pid), En =:= E] of
                [D | _] -> Fun(P, Pid, D);
                [] -> {error, 404, <<"not_found">>, <<"entity">>,
                       <<"no described Avatar entity ", E/binary, " in pairing ", P/binary>>}
            end;
        error ->
            {error, 404, <<"not_found">>, <<"pairing">>,
             <<"no WoT consumer is configured for pairing ", P/binary, " (http option things, docs/wot.md)">>}
    end.

safe_things(Pid) ->
    try evatar_web_thing:things(Pid)
    catch exit:_ -> []
    end.

input(<<>>) -> {ok, []};
input(Body) ->
    case evatar_json:decode(Body, #{max_size => byte_size(Body)}) of
        {ok, Map} when is_map(Map) ->
            case [K || {K, V} <- maps:to_list(Map), not is_binary(V)] of
                [] -> {ok, maps:to_list(Map)};
                [K | _] -> {error, <<"input parameter ", K/binary, " must be a string">>}
            end;
        {ok, _} -> {error, <<"the input must be a JSON object of parameter names and string values">>};
        {error, R} -> {error, evatar_json:format_error(R)}
    end.

answer({ok, #{context := feedback, origin := evatar, body := #{type := T}} = Sig}) ->
    Message = proplists:get_value(<<"Message">>, maps:get(parameters, maps:get(body, Sig)), T),
    case bil:keyword(T) of
        <<"timeout">> ->
            {error, 504, <<"feedback_timeout">>, null,
             <<"the Avatar did not answer within the pairing's feedback timeout: ", Message/binary>>};
        _ ->
            {error, 503, <<"provider_gone">>, null, Message}
    end;
answer({ok, #{context := error, origin := evatar, body := #{type := T} = B}}) ->
    Message = proplists:get_value(<<"Message">>, maps:get(parameters, B), T),
    {error, 409, <<"not_bound">>, null, <<"EVATAR refused the request (", T/binary, "): ", Message/binary>>};
answer({ok, #{context := error, body := #{type := T} = B}}) ->
    Message = proplists:get_value(<<"Message">>, maps:get(parameters, B), T),
    {error, 502, <<"device_error">>, null, <<"the Avatar answered ", T/binary, ": ", Message/binary>>};
answer({ok, Sig}) ->
    {200, params(Sig)};
answer({error, {not_joined, {refused, occupied}}}) ->
    {error, 503, <<"not_joined">>, null,
     <<"the pairing's agent slot is taken (a VA is joined): the WoT consumer joins when it is free">>};
answer({error, {not_joined, {refused, Why}}}) ->
    {error, 503, <<"not_joined">>, null,
     iolist_to_binary(["the WoT consumer is not joined to the pairing: ", atom_to_binary(Why)])};
answer({error, no_answer}) ->
    {error, 504, <<"feedback_timeout">>, null, <<"no answer from the pairing">>};
answer({error, no_reading}) ->
    {error, 503, <<"no_reading">>, null, <<"the sensor has not pushed a reading yet">>};
answer({error, What}) when What =:= no_such_action; What =:= no_such_property ->
    {error, 404, <<"not_found">>, null, <<"no such component and service in this Thing">>}.

%% A signal's parameters as a JSON object (the first of a repeated name),
%% and its timestamp.
params(#{body := #{parameters := Ps}, timestamp := Ts}) ->
    maps:merge(#{<<"timestamp">> => Ts},
               maps:from_list(lists:reverse([{K, V} || {K, V} <- Ps]))).

td_reply(TD) ->
    {raw, 200, [{"content-type", ?TD_TYPE}, {"cache-control", "no-store"}], evatar_json:encode(TD)}.

%% The address a client reached the node at, for the TDs' `base'.
base(#{headers := Headers}) ->
    Scheme = case evatar_web:url() of
                 "https" ++ _ -> "https://";
                 _ -> "http://"
             end,
    case maps:get(<<"host">>, Headers, <<>>) of
        Host when Host =/= <<>> ->
            unicode:characters_to_binary([Scheme, Host, "/"], latin1);
        _ ->
            unicode:characters_to_binary(evatar_web:url())
    end.
