%% @doc Properties of the pure session logic (in-flight window, packet ids,
%% retransmission) under random sequences of publishes, acknowledgements,
%% reconnects and retry ticks.
-module(mqtt_client_session_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").

-export([all/0, suite/0]).
-export([window_and_order/1, requests_survive_resume/1]).

suite() -> [{timetrap, {minutes, 1}}].

all() -> [window_and_order, requests_survive_resume].

%% @doc Whatever happens, at most `Window' messages are unacknowledged, a
%% packet id is never used twice at once, first transmissions follow publish
%% order, only unacknowledged messages are resent (with DUP), and once all is
%% acknowledged every message was acknowledged exactly once.
window_and_order(_Config) ->
    N = list_to_integer(os:getenv("MQTT_PROPER_N", "300")),
    ok = evatar_test_proper:check(
           ?FORALL({W, Cmds}, {range(1, 5), list(cmd())}, run(W, Cmds)), N).

cmd() ->
    frequency([{5, {publish, boolean()}}, {4, {ack, nat()}}, {1, {ack_unknown, nat()}},
               {1, resume}, {1, retry}]).

-record(m, {s, wire = #{}, next = 0, first_sent = [], acked = [], online = true}).

run(W, Cmds) ->
    M = lists:foldl(fun(C, M) -> step(C, M, W) end,
                    #m{s = mqtt_client_session:new(W)}, Cmds),
    %% Come back online and acknowledge everything.
    {Outs, S1} = mqtt_client_session:resume(0, M#m.s),
    M1 = drain(W, outs(Outs, M#m{s = S1})),
    All = lists:seq(0, M1#m.next - 1),
    ?WHENFAIL(ct:pal("~p~n~p", [Cmds, M1]),
              lists:sort(M1#m.acked) =:= All
              andalso lists:reverse(M1#m.first_sent) =:= All
              andalso mqtt_client_session:inflight_count(M1#m.s) =:= 0
              andalso mqtt_client_session:queue_len(M1#m.s) =:= 0).

drain(_W, #m{wire = Wire} = M) when map_size(Wire) =:= 0 ->
    M;
drain(W, M) ->
    drain(W, step({ack, 0}, M, W)).

step({publish, Online}, #m{next = I} = M, W) ->
    {Outs, S} = mqtt_client_session:publish(I, 0, Online, M#m.s),
    check(W, outs(Outs, M#m{s = S, next = I + 1}));
step({ack, K}, #m{wire = Wire} = M, W) when map_size(Wire) > 0 ->
    Ids = lists:sort(maps:keys(Wire)),
    Id = lists:nth(K rem length(Ids) + 1, Ids),
    {ok, Msg, Outs, S} = mqtt_client_session:puback(Id, 0, M#m.s),
    Msg = maps:get(Id, Wire),
    check(W, outs(Outs, M#m{s = S, wire = maps:remove(Id, Wire), acked = [Msg | M#m.acked]}));
step({ack, _}, M, _W) ->
    M;
step({ack_unknown, K}, #m{wire = Wire} = M, _W) ->
    Id = 1 + K rem 65535,
    case is_map_key(Id, Wire) of
        true -> M;
        false -> {error, unknown_packet_id} = mqtt_client_session:puback(Id, 0, M#m.s), M
    end;
step(resume, M, W) ->
    {Outs, S} = mqtt_client_session:resume(0, M#m.s),
    check(W, outs(Outs, M#m{s = S}));
step(retry, M, W) ->
    {Outs, S} = mqtt_client_session:retry(10, 5, M#m.s),
    check(W, outs(Outs, M#m{s = S})).

outs([], M) ->
    M;
outs([{publish, Id, Msg, Dup} | Rest], #m{wire = Wire} = M) ->
    M1 = case Dup of
             false ->
                 %% A new transmission: the id is free, the message is new.
                 false = is_map_key(Id, Wire),
                 false = lists:member(Msg, M#m.first_sent),
                 M#m{wire = Wire#{Id => Msg}, first_sent = [Msg | M#m.first_sent]};
             true ->
                 %% A retransmission: same id, same message, not yet acked.
                 Msg = maps:get(Id, Wire),
                 false = lists:member(Msg, M#m.acked),
                 M
         end,
    outs(Rest, M1).

check(W, M) ->
    true = map_size(M#m.wire) =< W,
    true = mqtt_client_session:inflight_count(M#m.s) =:= map_size(M#m.wire),
    M.

%% @doc A pending SUBSCRIBE keeps its packet id, is replayed by resume,
%% and its id is not handed to a publish while pending.
requests_survive_resume(_Config) ->
    S0 = mqtt_client_session:new(2),
    {Id, S1} = mqtt_client_session:request({subscribe, x}, S0),
    {[{publish, P1, a, false}], S2} = mqtt_client_session:publish(a, 0, true, S1),
    true = P1 =/= Id,
    {[{publish, P1, a, true}, {request, Id, {subscribe, x}}], S3} =
        mqtt_client_session:resume(0, S2),
    {ok, {subscribe, x}, S4} = mqtt_client_session:request_done(Id, S3),
    error = mqtt_client_session:request_done(Id, S4),
    {[a], [], _} = mqtt_client_session:drain(S4).
