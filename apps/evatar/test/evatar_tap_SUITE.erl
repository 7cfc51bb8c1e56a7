%% @doc Common Test suite of the live signal tail (evatar_tap): what a
%% watcher sees of a pairing's traffic, its filters, its bounded window with
%% the `dropped' marker, the removal of dead watchers, the cap per pairing,
%% and a watcher told when its pairing went.
-module(evatar_tap_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1,
         init_per_testcase/2, end_per_testcase/2]).
-export([tail_shows_traffic/1, filters/1, slow_watcher_is_bounded/1,
         dead_watcher_is_removed/1, too_many_watchers/1, pairing_gone/1,
         bad_filter/1]).

-include_lib("evatar_test_kit/include/evatar_entities.hrl").

suite() -> [{timetrap, {minutes, 2}}].

all() -> [tail_shows_traffic, filters, slow_watcher_is_bounded, dead_watcher_is_removed,
          too_many_watchers, pairing_gone, bad_filter].

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(evatar),
    Config.

end_per_suite(_Config) ->
    ok.

init_per_testcase(TC, Config) ->
    [{pairing, <<"tap_", (atom_to_binary(TC))/binary>>} | Config].

end_per_testcase(_TC, Config) ->
    _ = evatar:delete_pairing(?config(pairing, Config)),
    ok.

%% A pairing with a VA (a light emulator and a temperature sink) and an
%% Avatar (a light and a thermometer), bound.
bound_pairing(Config, Extra) ->
    bound_pairing(Config, Extra, fun(_) -> ok end).

%% `Before' runs once the pairing exists, before anybody joins.
bound_pairing(Config, Extra, Before) ->
    Id = ?config(pairing, Config),
    {ok, _} = evatar:create_pairing(Id, maps:merge(#{agent_credential => <<"a">>,
                                                     avatar_credential => <<"b">>,
                                                     join_timeout => 30000,
                                                     feedback_timeout => 30000}, Extra)),
    Result = Before(Id),
    {ok, Va, _} = ?E:start(Id, agent, ?VA, <<"a">>),
    {ok, Av, _} = ?E:start(Id, avatar, ?AV, <<"b">>),
    ok = evatar:describe(Va, ?E:description(?VA, [{?EMU, [], [{<<"ACTUATOR">>, <<"TurnLightOn">>}]},
                                                  {?SINK, [], [{<<"SENSOR">>, <<"temperature">>}]}])),
    ok = evatar:describe(Av, ?E:description(?AV, [{?LIGHT, [{<<"ACTUATOR">>, <<"TurnLightOn">>}], []},
                                                  {?THERMO, [{<<"SENSOR">>, <<"temperature">>}], []}])),
    _ = ?E:recv(?VA, bound),
    _ = ?E:recv(?VA, bound),
    _ = ?E:recv(?AV, bound),
    #{id => Id, va => Va, av => Av, before => Result}.

%% Items received by this process (the watcher) until `Pred' holds for the
%% list so far (the hang guard of evatar_test_time).
collect(Sub, Pred) ->
    collect(Sub, Pred, [], erlang:monotonic_time(millisecond) + evatar_test_time:guard()).

collect(Sub, Pred, Acc, Deadline) ->
    case Pred(Acc) of
        true ->
            {Acc, Sub};
        false ->
            Wait = max(0, Deadline - erlang:monotonic_time(millisecond)),
            receive
                Msg ->
                    case evatar_tap:handle(Msg, Sub) of
                        {items, Items, Sub1} -> collect(Sub1, Pred, Acc ++ Items, Deadline);
                        ignore -> collect(Sub, Pred, Acc, Deadline)
                    end
            after Wait ->
                    ct:fail({items_so_far, Acc})
            end
    end.

has(Kind) -> fun(Items) -> [I || #{kind := K} = I <- Items, K =:= Kind] =/= [] end.

kinds(Items) -> [K || #{kind := K} <- Items].

%% @doc A watcher sees a request and its feedback with their components, an
%% entity's join, EVATAR's refusal and its feedback timeout. The timeout is
%% fired on demand (evatar:expire_timer/2): a short one could also overtake
%% the answer to r1 on a loaded machine.
tail_shows_traffic(Config) ->
    #{va := Va, av := Av, id := Id, before := {ok, Sub}} =
        bound_pairing(Config, #{}, fun(Id) -> evatar_tap:watch(Id, #{}) end),
    ok = evatar:send(Va, ?E:signal(<<"r1">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r1">>} = ?E:recv(?AV, signal),
    ok = evatar:send(Av, ?E:signal(<<"f1">>, feedback, ?LIGHT, ?EMU, <<"r1">>)),
    #{id := <<"f1">>} = ?E:recv(?VA, signal),
    %% Not bound: the light does not consume the sink's service.
    ok = evatar:send(Av, ?E:signal(<<"x1">>, event, ?LIGHT, ?SINK)),
    #{context := error, in_reply_to := <<"x1">>} = ?E:recv(?AV, signal),
    ok = evatar:send(Va, ?E:signal(<<"r2">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r2">>} = ?E:recv(?AV, signal),
    ok = evatar:expire_timer(Id, {feedback, ?EMU, <<"r2">>}),
    {Items0, Sub1} = collect(Sub, has(<<"timeout">>)),
    %% The provider answers r2 after EVATAR closed it: refused as late.
    ok = evatar:send(Av, ?E:signal(<<"f2">>, feedback, ?LIGHT, ?EMU, <<"r2">>)),
    {Items, _} = collect(Sub1, has(<<"late">>), Items0,
                         erlang:monotonic_time(millisecond) + evatar_test_time:guard()),
    ct:log("~p", [Items]),
    [#{kind := <<"entity">>, what := <<"entity_joined">>, from_entity := ?VA, pairing := Id,
       at := At} | _] = Items,
    ?assert(is_integer(At)),
    [_] = [I || #{kind := <<"entity">>, what := <<"entity_joined">>, from_entity := ?AV} = I
                    <- Items],
    [#{from := ?EMU, to := ?LIGHT, from_entity := ?VA, to_entity := ?AV,
       category := <<"ACTUATOR">>, type := <<"TurnLightOn">>,
       parameters := [[<<"Light">>, <<"yes">>]]} | _] =
        [I || #{kind := <<"request">>} = I <- Items],
    [#{in_reply_to := <<"r1">>, from := ?LIGHT, to := ?EMU}] =
        [I || #{kind := <<"feedback">>} = I <- Items],
    [#{code := <<"NotBound">>, in_reply_to := <<"x1">>, to_entity := ?AV,
       from_entity := <<"EVATAR">>}] = [I || #{kind := <<"refusal">>} = I <- Items],
    [#{code := <<"Timeout">>, in_reply_to := <<"r2">>, to_entity := ?VA}] =
        [I || #{kind := <<"timeout">>} = I <- Items],
    [#{code := <<"RequestClosed">>, in_reply_to := <<"r2">>, to_entity := ?AV}] =
        [I || #{kind := <<"void">>} = I <- Items],
    [#{code := <<"NoOpenRequest">>, in_reply_to := <<"f2">>, to_entity := ?AV}] =
        [I || #{kind := <<"late">>} = I <- Items],
    ?assert(lists:member(<<"bindings">>, kinds(Items))).

%% @doc Kind and entity filters let through only what they name (the
%% pairing filters, so the watcher receives nothing else).
filters(Config) ->
    #{id := Id, va := Va, av := Av} = bound_pairing(Config, #{}),
    {ok, F} = evatar_tap:filter(<<"sensor_data,feedback">>, <<>>),
    {ok, Sub} = evatar_tap:watch(Id, F),
    ok = evatar:send(Va, ?E:signal(<<"r1">>, request, ?EMU, ?LIGHT)),
    #{id := <<"r1">>} = ?E:recv(?AV, signal),
    ok = evatar:send(Av, ?E:signal(<<"f1">>, feedback, ?LIGHT, ?EMU, <<"r1">>)),
    ok = evatar:send(Av, ?E:signal(<<"s1">>, sensor_data, ?THERMO, ?SINK)),
    {Items, _} = collect(Sub, has(<<"sensor_data">>)),
    ?assertEqual([<<"feedback">>, <<"sensor_data">>], kinds(Items)),
    ok = evatar_tap:unwatch(Sub),
    {ok, G} = evatar_tap:filter(<<>>, <<"nobody">>),
    {ok, Sub2} = evatar_tap:watch(Id, G),
    {ok, H} = evatar_tap:filter(<<"sensor_data">>, ?VA),
    {ok, Sub3} = evatar_tap:watch(Id, H),
    ok = evatar:send(Av, ?E:signal(<<"s2">>, sensor_data, ?THERMO, ?SINK)),
    {[#{signal := <<"s2">>, to_entity := ?VA}], _} = collect(Sub3, has(<<"sensor_data">>)),
    %% The pairing handled s2 before the watcher got it: the entity filter
    %% that names nobody had its chance and sent nothing.
    ok = evatar_tap:unwatch(Sub2),
    receive {evatar_tap, _, _} = Unexpected -> ct:fail({unexpected, Unexpected})
    after 0 -> ok
    end.

%% @doc A watcher that never reads holds at most the window of messages,
%% whatever the traffic; routing goes on; its next acknowledgement brings
%% a `dropped' item with the exact count of what it missed.
slow_watcher_is_bounded(Config) ->
    #{id := Id, av := Av} = bound_pairing(Config, #{}),
    Self = self(),
    Watcher = spawn(fun() ->
                                 {ok, S} = evatar_tap:watch(Id, #{kinds => [<<"sensor_data">>]}),
                                 Self ! {watching, S},
                                 receive go -> ok end,
                                 Self ! {mailbox, erlang:process_info(self(), message_queue_len)},
                                 receive done -> ok end
                         end),
    receive {watching, _} -> ok end,
    Window = evatar_tap:window(),
    N = Window * 4,
    [ok = evatar:send(Av, ?E:signal(integer_to_binary(I), sensor_data, ?THERMO, ?SINK))
     || I <- lists:seq(1, N)],
    [#{id := _} = ?E:recv(?VA, signal) || _ <- lists:seq(1, N)],
    Watcher ! go,
    {message_queue_len, Window} = receive {mailbox, M} -> M end,
    {ok, 1} = wait_watchers(Id, 1),
    Watcher ! done,
    ok = wait_dead(Watcher),
    {ok, 0} = wait_watchers(Id, 0),
    %% The same again with this process as the watcher, reading the marker.
    {ok, Sub2} = evatar_tap:watch(Id, #{kinds => [<<"sensor_data">>]}),
    [ok = evatar:send(Av, ?E:signal(<<"b", (integer_to_binary(I))/binary>>, sensor_data,
                                    ?THERMO, ?SINK)) || I <- lists:seq(1, N)],
    [#{id := _} = ?E:recv(?VA, signal) || _ <- lists:seq(1, N)],
    {message_queue_len, Window} = erlang:process_info(self(), message_queue_len),
    {Items, Sub3} = collect(Sub2, fun(Is) -> length(Is) >= Window end),
    %% Reading half the window acknowledged it: the marker came at once,
    %% before the next signal.
    ok = evatar:send(Av, ?E:signal(<<"after">>, sensor_data, ?THERMO, ?SINK)),
    {More, _} = collect(Sub3, fun(Is) -> [x || #{signal := <<"after">>} <- Is] =/= [] end),
    ?assertEqual(Window, length(Items)),
    [#{kind := <<"dropped">>, count := Dropped}, #{signal := <<"after">>}] = More,
    ?assertEqual(N - Window, Dropped).

wait_dead(Pid) ->
    Ref = erlang:monitor(process, Pid),
    receive {'DOWN', Ref, process, Pid, _} -> ok end.

%% The pairing's count of watchers once it is `Want', or the last count
%% seen when the kit's hang guard passes.
wait_watchers(Id, Want) ->
    Probe = fun() ->
                    case gen_statem:call(evatar_registry:whereis_name(Id), {inspect, watchers}) of
                        Want -> true;
                        Other -> {false, Other}
                    end
            end,
    case evatar_test_wait:poll(Probe, #{interval => 50}) of
        ok -> {ok, Want};
        {error, {wait_timeout, #{last_seen := Other}}} -> {error, Other}
    end.

%% @doc A watcher that dies is removed from its pairing.
dead_watcher_is_removed(Config) ->
    #{id := Id} = bound_pairing(Config, #{}),
    Self = self(),
    Pids = [spawn(fun() -> {ok, _} = evatar_tap:watch(Id, #{}), Self ! {ok, self()},
                           receive stop -> ok end end) || _ <- lists:seq(1, 3)],
    [receive {ok, P} -> ok end || P <- Pids],
    {ok, 3} = wait_watchers(Id, 3),
    [exit(P, kill) || P <- Pids],
    {ok, 0} = wait_watchers(Id, 0).

%% @doc At most 16 watchers per pairing; the next is refused.
too_many_watchers(Config) ->
    #{id := Id} = bound_pairing(Config, #{}),
    Subs = [begin {ok, S} = evatar_tap:watch(Id, #{}), S end || _ <- lists:seq(1, 16)],
    {error, too_many_watchers} = evatar_tap:watch(Id, #{}),
    ok = evatar_tap:unwatch(hd(Subs)),
    {ok, 15} = wait_watchers(Id, 15),
    {ok, _} = evatar_tap:watch(Id, #{}).

%% @doc A deleted pairing: the watcher is told (`moved', role `gone'); an
%% unknown pairing cannot be watched.
pairing_gone(Config) ->
    #{id := Id} = bound_pairing(Config, #{}),
    {ok, Sub} = evatar_tap:watch(Id, #{}),
    ok = evatar:delete_pairing(Id),
    {Items, _} = collect(Sub, has(<<"moved">>)),
    [#{role := <<"gone">>, pairing := Id}] = [I || #{kind := <<"moved">>} = I <- Items],
    {error, not_found} = evatar_tap:watch(<<"no such pairing">>, #{}).

%% @doc A filter naming an unknown kind is refused with that kind.
bad_filter(_Config) ->
    {error, {bad_kind, <<"bogus">>}} = evatar_tap:filter(<<"request,bogus">>, <<>>),
    {ok, #{}} = evatar_tap:filter(<<>>, <<>>),
    {ok, #{kinds := [<<"feedback">>, <<"request">>], entity := <<"e">>}} =
        evatar_tap:filter(<<"request,feedback,">>, <<"e">>).
