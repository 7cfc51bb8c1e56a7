%% @doc The narrator of a scenario: every VA tells it what it perceived,
%% decided and did; it stamps each line with the simulated time, prints it
%% when asked to (the demo) and keeps the whole story so tests can read it
%% back ({@link events/1}). Public (rebar.config's `Public'): the demo's
%% scenarios (evatar_demo) start it, give it to their VAs and read it.
-module(reference_agents_narrator).
-behaviour(gen_server).

-export([start_link/1, stop/1, event/4, events/1, count/1, format_time/1]).
-export([init/1, handle_call/3, handle_cast/2]).

-export_type([event/0, opts/0, kind/0]).

-type kind() :: perceive | decide | act | info | world.
-type event() :: #{time := integer(), who := binary(), kind := kind(), text := binary()}.
%% `clock' gives the time to stamp events with (ms since 1970, simulated in
%% the scenarios); `print' writes each event as it comes to `io' (a device
%% or group leader, the caller's by default).
-type opts() :: #{clock := fun(() -> integer()), print => boolean(), io => pid() | atom()}.

-record(s, {clock :: fun(() -> integer()),
            print :: boolean(),
            io :: pid() | atom(),
            events = [] :: [event()]}).

-spec start_link(opts()) -> {ok, pid()}.
start_link(Opts) ->
    Io = maps:get(io, Opts, group_leader()),
    gen_server:start_link(?MODULE, Opts#{io => Io}, []).

-spec stop(pid()) -> ok.
stop(N) -> gen_server:stop(N).

%% @doc Tells the story one line further. `undefined' narrates nothing.
-spec event(pid() | undefined, binary(), kind(), iodata()) -> ok.
event(undefined, _Who, _Kind, _Text) -> ok;
event(N, Who, Kind, Text) ->
    gen_server:cast(N, {event, Who, Kind, iolist_to_binary(Text)}).

%% @doc Every event so far, oldest first.
-spec events(pid()) -> [event()].
events(N) -> gen_server:call(N, events).

%% @doc How many events so far: a cheap call, and once it returns every
%% event the caller (or a process it heard from) sent before is stamped.
-spec count(pid()) -> non_neg_integer().
count(N) -> gen_server:call(N, count).

%% @doc `18:02:13' for a time in ms since 1970 (UTC: the simulated houses
%% keep their clock in UTC).
-spec format_time(integer()) -> string().
format_time(Ms) ->
    {_, {H, M, S}} = calendar:system_time_to_universal_time(Ms, millisecond),
    io_lib:format("~2..0b:~2..0b:~2..0b", [H, M, S]).

-spec init(opts()) -> {ok, #s{}}.
init(#{clock := Clock, io := Io} = Opts) ->
    {ok, #s{clock = Clock, print = maps:get(print, Opts, false), io = Io}}.

-spec handle_call(events | count, gen_server:from(), #s{}) ->
          {reply, [event()] | non_neg_integer(), #s{}}.
handle_call(events, _From, #s{events = Es} = S) ->
    {reply, lists:reverse(Es), S};
handle_call(count, _From, #s{events = Es} = S) ->
    {reply, length(Es), S}.

-spec handle_cast({event, binary(), kind(), binary()}, #s{}) -> {noreply, #s{}}.
handle_cast({event, Who, Kind, Text}, #s{clock = Clock} = S) ->
    Time = Clock(),
    E = #{time => Time, who => Who, kind => Kind, text => Text},
    case S#s.print of
        true -> io:format(S#s.io, "[~s] ~-16s ~-9s ~ts~n",
                          [format_time(Time), Who, label(Kind), Text]);
        false -> ok
    end,
    {noreply, S#s{events = [E | S#s.events]}}.

label(perceive) -> "PERCEIVE";
label(decide) -> "DECIDE";
label(act) -> "ACT";
label(info) -> "";
label(world) -> "WORLD".
