%% @doc The cost of the live tail per routed signal (evatar_tap, the
%% dashboard's signal stream): what evatar_pairing:step/2 does with no
%% watcher (one match on `[]') and with one watcher taking every item
%% (building the item, filtering, one message), for the effects of a
%% routed request; three rounds of 1,000,000 calls, the watcher's mailbox
%% drained between rounds. Not part of the product; bench/EVATAR_BENCH.md,
%% "The live tail", gives the figures.
-module(tap_bench).

-export([main/0]).

-define(N, 1000000).

%% @doc Prints ns per call, three rounds.
-spec main() -> ok.
main() ->
    Signal = #{context => request, id => <<"va1-1">>, sender => <<"LightEmulator01">>,
               receiver => <<"HomeLightActuator01">>, in_reply_to => undefined, seq => 7,
               epoch => 1, timestamp => 0,
               body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                         parameters => [{<<"Light">>, <<"on">>}]}},
    Event = {signal, <<"va1">>, Signal},
    Effects = [{deliver, <<"7008">>, Signal},
               {start_timer, {feedback, <<"LightEmulator01">>, <<"va1-1">>}, 5000},
               {accepted, <<"va1">>, <<"va1-1">>}],
    Sink = spawn(fun sink/0),
    %% The same watcher list every call: a full window each time, so every
    %% call builds and sends.
    {ok, _, One} = evatar_tap:add(Sink, #{}, [], <<"bench">>),
    lists:foreach(
      fun(Round) ->
              Empty = ns(fun() -> case [] of [] -> ok; W -> W end end),
              Watched = ns(fun() -> _ = evatar_tap:emit(<<"bench">>, Event, Effects, 0,
                                                        One), ok end),
              Sink ! {drain, self()},
              receive drained -> ok end,
              io:format("round ~b: no watcher ~.1f ns, one watcher ~.1f ns per routed signal; "
                        "load average ~s~n", [Round, Empty, Watched, load()])
      end, [1, 2, 3]).

sink() ->
    receive
        {drain, From} -> drain(), From ! drained, sink();
        _ -> sink()
    end.

drain() ->
    receive {evatar_tap, _, _} -> drain() after 0 -> ok end.

ns(F) ->
    {T, ok} = timer:tc(fun() -> loop(?N, F) end),
    T * 1000 / ?N.

loop(0, _F) -> ok;
loop(N, F) -> _ = F(), loop(N - 1, F).

load() ->
    case file:read_file("/proc/loadavg") of
        {ok, B} -> hd(string:split(string:trim(B), " "));
        {error, _} -> "?"
    end.
