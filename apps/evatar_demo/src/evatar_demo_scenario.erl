%% @doc Internal. What every scenario needs around its VAs: the EVATAR and
%% bridge applications (started if they are not running, without the
%% default listener), a listener of its own on a free loopback port, the
%% pairings, a narrator, the VAs, and the way to wait for things to happen
%% and to clean everything up again.
-module(evatar_demo_scenario).

-export([start/1, pairing/3, start_va/2, await/3, await_va_state/4, await_described/3, embodied/1,
         follow/2, lockstep/2, quiet/1, settle/1,
         narrator/1, endpoint/1, stop/1, examples_dir/0, priv_dir/0, body/1,
         body_subset/3, add/3, get/2, say/3, on_stop/2]).

-export_type([scenario/0]).

-opaque scenario() :: #{listener := term(), endpoint := {inet:ip_address(), inet:port_number()},
                        started := [atom()], restore := fun(() -> ok),
                        narrator := pid(), pairings := [binary()], vas := [pid()],
                        extra := map()}.

%% @doc Starts the applications, a simulation clock (`clock' holds its
%% options; kept as `clock'), a listener and a narrator that stamps events
%% with simulated time. `print' makes the narrator write each event as it
%% happens.
-spec start(#{name := term(), clock := map(), print => boolean(),
              io => pid() | atom()}) -> {ok, scenario()}.
start(#{name := Name, clock := ClockOpts} = Opts) ->
    {Started, Restore} = start_apps(),
    {ok, SimClock} = avatar_sim:start_clock(ClockOpts),
    Clock = fun() -> avatar_sim:now(SimClock) end,
    Listener = {evatar_demo, Name, erlang:unique_integer([positive])},
    {ok, _} = agent_bridge:start_listener(Listener, #{ip => {127, 0, 0, 1}, port => 0}),
    {ok, Endpoint} = agent_bridge:address(Listener),
    {ok, Narrator} = reference_agents_narrator:start_link((maps:with([print, io], Opts))#{clock => Clock}),
    {ok, #{listener => Listener, endpoint => Endpoint, started => Started, restore => Restore,
           narrator => Narrator, pairings => [], vas => [], extra => #{clock => SimClock}}}.

%% Starts what is not running, without the default listener on port 7400.
start_apps() ->
    case lists:keymember(agent_bridge, 1, application:which_applications()) of
        true ->
            {ok, S} = application:ensure_all_started(avatar_sim),
            {S, fun() -> ok end};
        false ->
            _ = application:load(agent_bridge),
            Saved = application:get_env(agent_bridge, listeners),
            ok = application:set_env(agent_bridge, listeners, []),
            {ok, S1} = application:ensure_all_started(agent_bridge),
            {ok, S2} = application:ensure_all_started(avatar_sim),
            {S1 ++ S2, fun() ->
                               case Saved of
                                   undefined -> application:unset_env(agent_bridge, listeners);
                                   {ok, V} -> application:set_env(agent_bridge, listeners, V)
                               end
                       end}
    end.

%% @doc Creates a pairing with the given credentials; a feedback timeout
%% (real ms) can be given.
-spec pairing(binary(), map(), scenario()) -> scenario().
pairing(Id, Opts, #{pairings := Ps} = S) ->
    {ok, _} = evatar:create_pairing(Id, Opts),
    S#{pairings := [Id | Ps]}.

%% @doc Starts a VA (reference_agents:start_va/1 options; endpoints and narrator
%% are filled in).
-spec start_va(reference_agents:va_opts(), scenario()) -> {pid(), scenario()}.
start_va(Opts, #{endpoint := E, narrator := N, vas := Vas} = S) ->
    {ok, Pid} = reference_agents:start_va(
                  maps:merge(#{endpoints => [E], narrator => N}, Opts)),
    {Pid, S#{vas := [Pid | Vas]}}.

%% @doc Waits (real time, polling every 20 ms) until `Pred()' gives
%% `{true, Value}'; `{error, timeout}' after `Ms'.
-spec await(fun(() -> {true, term()} | false), non_neg_integer(), term()) ->
          {ok, term()} | {error, {timeout, term()}}.
await(Pred, Ms, What) ->
    Deadline = erlang:monotonic_time(millisecond) + Ms,
    await_loop(Pred, Deadline, What).

await_loop(Pred, Deadline, What) ->
    case Pred() of
        {true, V} -> {ok, V};
        false ->
            case erlang:monotonic_time(millisecond) >= Deadline of
                true -> {error, {timeout, What}};
                false -> receive after 20 -> await_loop(Pred, Deadline, What) end
            end
    end.

%% @doc Waits until the VA is in one of `States'.
-spec await_va_state(pid(), [atom()], non_neg_integer(), term()) ->
          {ok, map()} | {error, {timeout, term()}}.
await_va_state(Va, States, Ms, What) ->
    await(fun() ->
                  #{state := St} = I = reference_agents:inspect(Va),
                  case lists:member(St, States) of
                      true -> {true, I};
                      false -> false
                  end
          end, Ms, What).

%% @doc Waits (real time) until the Avatars of pairing `Id' have joined and
%% described every component of `Ids', as EVATAR's Service Registration
%% List shows them: a VA that joins next is bound to all of them in its
%% first Binding report. An Avatar that connected has not necessarily been
%% registered yet (its description is on its way to the pairing), and a VA
%% started then tests a body that is not there yet ("not bound by EVATAR").
%% After `Ms', an error naming the components still missing.
-spec await_described(evatar:pairing_id(), [binary()], non_neg_integer()) ->
          ok | {error, {not_described, evatar:pairing_id(), [binary()]}}.
await_described(Id, Ids, Ms) ->
    Missing = fun() -> Ids -- described(Id) end,
    case await(fun() -> Missing() =:= [] andalso {true, ok} end, Ms, described) of
        {ok, ok} -> ok;
        {error, _} -> {error, {not_described, Id, Missing()}}
    end.

described(Id) ->
    case evatar:registry(Id) of
        {ok, Entries} ->
            [C || #{role := avatar, description := #{components := Cs}} <- Entries,
                  #{id := C} <- Cs];
        {error, _} ->
            []
    end.

%% @doc True when the VA's last embodiment test passed completely.
-spec embodied(pid()) -> boolean().
embodied(Va) ->
    case reference_agents:inspect(Va) of
        #{state := embodied, embodiment := #{verdict := embodied}} -> true;
        _ -> false
    end.

-spec narrator(scenario()) -> pid().
narrator(#{narrator := N}) -> N.

-spec endpoint(scenario()) -> {inet:ip_address(), inet:port_number()}.
endpoint(#{endpoint := E}) -> E.

%% @doc The scenario's clock follows a VA started with option `seen =>
%% Seen' (reference_agents_va): it never runs more than two simulated
%% minutes (two of the time sensor's periods) ahead of the latest time the
%% VA has perceived (avatar_sim:follow/3). For a house whose traffic the
%% scenario cannot count (its devices on MQTT); the VAs act in real time on
%% a clock a thousand times faster, so how far behind the clock a VA acts
%% depends on the machine's load. {@link lockstep/2} does not.
-spec follow(scenario(), atomics:atomics_ref()) -> scenario().
follow(#{extra := #{clock := Clock}} = S, Seen) ->
    ok = avatar_sim:follow(Clock, fun() -> perceived(Seen) end, 120000),
    add(seen, Seen, S).

%% @doc With the clock paused: waits until the VA the clock follows has
%% perceived the house's last time reading and no VA awaits an answer, so
%% an outcome read next is the whole of the run so far (30 s at most).
-spec settle(scenario()) -> ok | {error, {timeout, settled}}.
settle(#{vas := Vas, extra := #{seen := Seen, home := Home}}) ->
    Last = lists:max([0 | [T || #{time := T, context := sensor_data, params := Ps}
                                    <- avatar_sim:log(Home),
                                lists:keymember(<<"TimeOfDay">>, 1, Ps)]]),
    Settled = fun() ->
                      atomics:get(Seen, 1) >= Last andalso
                          lists:all(fun(Va) -> maps:get(pending, reference_agents:inspect(Va)) =:= 0
                                    end, Vas)
                          andalso {true, ok}
              end,
    case await(Settled, 30000, settled) of
        {ok, ok} -> ok;
        {error, _} = E -> E
    end;
settle(#{}) ->
    ok.

%% @doc The scenario's clock runs in lockstep with its VAs, its pairings
%% and its simulated worlds (avatar_sim:lockstep/2): a tick starts only
%% when {@link quiet/1} holds. What a VA perceives and does then lands at
%% the same tick however slow the machine, so the run's outcome is the same
%% on an idle and on a busy one. `Seen' is kept for settle/1, as with
%% follow/2.
-spec lockstep(scenario(), atomics:atomics_ref()) -> scenario().
lockstep(#{extra := #{clock := Clock}} = S, Seen) ->
    ok = avatar_sim:lockstep(Clock, fun() -> quiet(S) end),
    add(seen, Seen, S).

%% @doc Whether nothing the simulation set going is on its way or being
%% handled: every embodied VA has handled every signal its pairing has
%% delivered to it and every MAS message told to it, its pairing has every
%% signal it sent, and likewise for each connected link of the worlds
%% (avatar_sim:links/1), whose world has handled every request passed to it.
%% Counts are read receiving side first, then sending side, so equal counts
%% mean that at one moment between the two reads nothing was in flight nor
%% being handled (a message counts as received once handled, and what it
%% made its receiver send is counted before that). Requests the worlds are
%% still carrying out (a photo burst, a robot's GoTo) hold nothing: they
%% answer at a later tick. A VA that is not embodied (testing its body,
%% which has real-time timeouts) and entities the scenario does not run
%% (an MQTT Avatar) are not counted. The narrator has stamped, before the
%% next tick, every event told it so far.
-spec quiet(scenario()) -> boolean().
quiet(#{pairings := Ps, vas := Vas, narrator := N, extra := X}) ->
    Worlds = maps:get(avatars, X, []),
    Received = traffic(Ps, received),
    VasIn = va_traffic(Vas),
    LinksIn = link_traffic(Worlds),
    %% avatar_sim:links/1 asks each world first: it has then handled every
    %% request its links passed it before they answered above, and the links
    %% answer next with what it emitted counted.
    LinksOut = link_traffic(Worlds),
    VasOut = va_traffic(Vas),
    Delivered = traffic(Ps, delivered),
    %% The story is stamped with the tick its tellers acted in.
    _ = reference_agents_narrator:count(N),
    maps:keys(VasIn) =:= maps:keys(VasOut) andalso
        maps:keys(LinksIn) =:= maps:keys(LinksOut) andalso
        lists:sum([H || {_, _, {H, _}} <- maps:values(VasIn)])
        =:= lists:sum([T || {_, _, {_, T}} <- maps:values(VasOut)]) andalso
        lists:all(fun({E, {In, _, _}}) -> maps:get(E, Delivered, 0) =:= In end,
                  maps:to_list(maps:merge(LinksIn, VasIn))) andalso
        lists:all(fun({E, {_, Out, _}}) -> maps:get(E, Received, 0) =:= Out end,
                  maps:to_list(maps:merge(LinksOut, VasOut))).

%% Entity -> the count `Key' of the pairings' traffic (evatar:traffic/1).
traffic(Ps, Key) ->
    maps:from_list([{E, maps:get(Key, C)} || P <- Ps, {ok, #{entities := Es}} <- [evatar:traffic(P)],
                                             {E, C} <- maps:to_list(Es)]).

%% Entity -> {In, Out, {Heard, Told}} of the embodied VAs that are alive.
va_traffic(Vas) ->
    Heard = fun(#{heard := H}) -> H end,
    Told = fun(#{told := T}) -> T end,
    maps:from_list([{E, {In, Out, {Heard(T), Told(T)}}}
                    || Va <- Vas, is_process_alive(Va),
                       #{state := embodied, entity := E, in := In, out := Out} = T
                           <- [reference_agents:traffic(Va)]]).

%% Entity -> {In, Out, {0, 0}} of the connected links of the worlds.
link_traffic(Worlds) ->
    maps:from_list([{E, {In, Out, {0, 0}}}
                    || W <- Worlds, #{state := connected, entity := E, in := In, out := Out}
                                        <- avatar_sim:links(W)]).

perceived(Seen) ->
    case atomics:get(Seen, 1) of
        0 -> undefined;
        T -> T
    end.

%% @doc Keeps a value with the scenario (avatars, clock, ...).
-spec add(atom(), term(), scenario()) -> scenario().
add(Key, Value, #{extra := X} = S) -> S#{extra := X#{Key => Value}}.

%% @doc Something to clean up when the scenario stops (an MQTT home, a
%% broker): run after the VAs are stopped, the last added first.
-spec on_stop(fun(() -> term()), scenario()) -> scenario().
on_stop(Fun, #{extra := X} = S) ->
    S#{extra := X#{on_stop => [Fun | maps:get(on_stop, X, [])]}}.

-spec get(atom(), scenario()) -> term().
get(Key, #{extra := X}) -> maps:get(Key, X).

%% @doc A line of the story told by the scenario itself (not by a VA).
-spec say(scenario(), reference_agents_narrator:kind(), iodata()) -> ok.
say(#{narrator := N}, Kind, Text) ->
    reference_agents_narrator:event(N, <<"scenario">>, Kind, Text).

%% @doc Stops the VAs, the Avatars kept under `avatars', the pairings, the
%% listener, the narrator and the applications the scenario started.
-spec stop(scenario()) -> ok.
stop(#{vas := Vas, pairings := Ps, listener := L, narrator := N, started := Started,
       restore := Restore, extra := X}) ->
    %% Time stands still while the scenario goes (a clock in lockstep reads
    %% the VAs and worlds stopped next).
    _ = [catch avatar_sim:pause(C) || #{clock := C} <- [X]],
    lists:foreach(fun(Va) -> catch reference_agents:stop_va(Va) end, Vas),
    lists:foreach(fun(F) -> catch F() end, maps:get(on_stop, X, [])),
    lists:foreach(fun(A) -> catch avatar_sim:stop(A) end, maps:get(avatars, X, [])),
    case X of
        #{clock := Clock} -> catch avatar_sim:stop_clock(Clock);
        _ -> ok
    end,
    lists:foreach(fun(P) -> _ = evatar:delete_pairing(P) end, Ps),
    ok = agent_bridge:stop_listener(L),
    ok = reference_agents_narrator:stop(N),
    lists:foreach(fun application:stop/1, lists:reverse(Started)),
    Restore().

%% @doc apps/bil/priv/examples.
-spec examples_dir() -> file:filename().
examples_dir() -> filename:join(code:priv_dir(bil), "examples").

-spec priv_dir() -> file:filename().
priv_dir() -> code:priv_dir(reference_agents).

%% @doc A description from the BIL examples.
-spec body(string()) -> bil:description().
body(File) ->
    {ok, Xml} = file:read_file(filename:join(examples_dir(), File)),
    {ok, D} = bil:parse_description(Xml),
    D.

%% @doc A description with another EntityID and only the given components.
-spec body_subset(bil:description(), binary(), [binary()] | all) -> bil:description().
body_subset(D, EntityId, all) ->
    D#{entity_id := EntityId};
body_subset(#{components := Cs} = D, EntityId, Ids) ->
    D#{entity_id := EntityId, components := [C || #{id := Id} = C <- Cs, lists:member(Id, Ids)]}.
