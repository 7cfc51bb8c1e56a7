%% @doc Public API of avatar_sim: simulated Avatars that join EVATAR over TCP
%% exactly as device software would. `start_arena/1' starts the LEGO arena
%% of the paper's section 3.1 (two robots, three balls), `start_home/1' the
%% easy smart home of section 3.2, both on a deterministic simulation clock
%% (`start_clock/1'). docs/avatars.md is the full contract: options,
%% components, requests, answers and sensor signals.
-module(avatar_sim).

-export([start_clock/1, stop_clock/1, now/1, advance/2, pause/1, resume/1, set_speed/2,
         clock_info/1, follow/3, lockstep/2]).
-export([start_arena/1, start_home/1, stop/1, state/1, log/1, links/1, clock/1,
         act/3, place_ball/4]).
-export([mute/2, unmute/2, disconnect/2, disconnect/3, reconnect/2, detach_device/2,
         attach_device/2]).

-export_type([avatar/0, clock/0, arena_opts/0, home_opts/0, link_opts/0, log_entry/0]).

-type avatar() :: pid().
-type clock() :: avatar_sim_clock:clock().
-type link_opts() :: #{pairing => binary(), credential => binary(), entity_id => binary()}.
-type common_opts() :: #{clock => clock() | avatar_sim_clock:opts(),
                         seed => integer(),
                         endpoints => [agent_bridge_client:endpoint()],
                         retry => pos_integer()}.
-type arena_opts() :: #{robots => [map()], balls => [map()], zones => [map()],
                        width => pos_integer(), height => pos_integer(),
                        light_period => non_neg_integer(),
                        progress_interval => pos_integer(),
                        atom() => term()}.
-type home_opts() :: #{gateways => [map()], spool => file:filename_all(),
                       password => binary(), email_to => binary(), email_from => binary(),
                       script => [avatar_sim_script:step()], script_file => file:filename_all(),
                       people => #{binary() => binary()}, location => map(),
                       time_period => pos_integer(), motion_repeat => pos_integer(),
                       motion_quiet => non_neg_integer(), atom() => term()}.
-type log_entry() :: #{time := integer(), entity := binary() | undefined,
                       component := binary(), context := bil:signal_context(),
                       type := binary(), params := [{binary(), binary()}]}.


%% ---------------------------------------------------------------------------
%% Clock
%% ---------------------------------------------------------------------------

%% @doc Starts a simulation clock (docs/avatars.md section 2) that several
%% Avatars (and tests) can share.
-spec start_clock(avatar_sim_clock:opts()) -> {ok, clock()}.
start_clock(Opts) ->
    {ok, _Pid, Clock} = avatar_sim_sup:start_child(
                          #{start => {avatar_sim_clock, start_link, [Opts]}}),
    {ok, Clock}.

-spec stop_clock(clock()) -> ok.
stop_clock(Clock) -> avatar_sim_clock:stop(Clock).

%% @doc Simulated time, ms since 1970-01-01 UTC.
-spec now(clock()) -> integer().
now(Clock) -> avatar_sim_clock:now(Clock).

%% @doc Runs `Ms' of simulated time now and returns when every world has
%% handled it.
-spec advance(clock(), non_neg_integer()) -> ok.
advance(Clock, Ms) -> avatar_sim_clock:advance(Clock, Ms).

-spec pause(clock()) -> ok.
pause(Clock) -> avatar_sim_clock:pause(Clock).

-spec resume(clock()) -> ok.
resume(Clock) -> avatar_sim_clock:resume(Clock).

-spec set_speed(clock(), avatar_sim_clock:speed()) -> ok.
set_speed(Clock, Speed) -> avatar_sim_clock:set_speed(Clock, Speed).

-spec clock_info(clock()) -> map().
clock_info(Clock) -> avatar_sim_clock:info(Clock).

%% @doc Paces the clock by an observer (docs/avatars.md section 2): ticks
%% wait while simulated time would run more than `LeadMs' ahead of
%% `Seen()', the simulated time the observer has perceived (`undefined'
%% while it has perceived nothing); `none' stops following.
-spec follow(clock(), avatar_sim_clock:seen() | none, non_neg_integer()) -> ok.
follow(Clock, Seen, LeadMs) -> avatar_sim_clock:follow(Clock, Seen, LeadMs).

%% @doc Runs the clock in lockstep (docs/avatars.md section 2): a paced tick
%% starts only once `Quiet()' says that everything the last ones set going
%% has been handled; `none' stops it. Replaces a {@link follow/3}.
-spec lockstep(clock(), avatar_sim_clock:quiet() | none) -> ok.
lockstep(Clock, Quiet) -> avatar_sim_clock:lockstep(Clock, Quiet).

%% ---------------------------------------------------------------------------
%% Avatars
%% ---------------------------------------------------------------------------

%% @doc Starts the LEGO arena and its robots; each robot with a `pairing'
%% joins it (docs/avatars.md section 3).
-spec start_arena(common_opts() | arena_opts()) -> {ok, avatar()} | {error, term()}.
start_arena(Opts) ->
    Base = avatar_sim_desc:example("lego_robot.xml"),
    Robots0 = maps:get(robots, Opts, [#{}, #{}]),
    Defaults = [{300, 300, 0}, {1700, 1200, 180}],
    Robots = [robot_opts(I, R, Base, Defaults)
              || {I, R} <- lists:zip(lists:seq(1, length(Robots0)), Robots0)],
    Links = [link_spec(R, Opts) || R <- Robots],
    ModelOpts = maps:merge(maps:with([balls, zones, width, height, light_period,
                                      progress_interval, seed], Opts),
                           #{robots => Robots}),
    start_world(avatar_sim_robots, ModelOpts, Opts#{links => Links}).

robot_opts(I, R, Base, Defaults) ->
    {X, Y, H} = case I =< length(Defaults) of
                    true -> lists:nth(I, Defaults);
                    false -> {300 + 200 * I, 750, 0}
                end,
    Entity = maps:get(entity_id, R, avatar_sim_desc:robot_entity(I)),
    Desc = (avatar_sim_desc:robot(I, Base))#{entity_id := Entity},
    R1 = maps:merge(#{x => X, y => Y, heading => H}, R),
    R1#{index => I, entity => Entity, description => Desc}.

%% @doc Starts the smart home: its devices, its people and their script,
%% joining through its gateways (docs/avatars.md section 4).
-spec start_home(common_opts() | home_opts()) -> {ok, avatar()} | {error, term()}.
start_home(Opts) ->
    case script(Opts) of
        {ok, Script} ->
            Desc = avatar_sim_desc:example("smart_home.xml"),
            Gateways0 = maps:get(gateways, Opts, [#{}]),
            Gateways = [gateway(I, G, Desc)
                        || {I, G} <- lists:zip(lists:seq(1, length(Gateways0)), Gateways0)],
            Spool = filename:absname(maps:get(spool, Opts, "spool")),
            ModelOpts = maps:merge(maps:with([password, email_to, email_from, people, location,
                                              time_period, motion_repeat, motion_quiet, seed],
                                             Opts),
                                   #{description => Desc, spool => Spool, script => Script}),
            start_world(avatar_sim_house, ModelOpts,
                        Opts#{links => [link_spec(G, Opts) || G <- Gateways]});
        {error, _} = Error ->
            Error
    end.

script(#{script_file := File}) ->
    case file:read_file(File) of
        {ok, Text} -> avatar_sim_script:parse(Text);
        {error, Why} -> {error, {script_file, File, Why}}
    end;
script(Opts) ->
    avatar_sim_script:check(maps:get(script, Opts, [])).

gateway(I, G, Desc) ->
    Base = maps:get(entity_id, Desc),
    Entity = maps:get(entity_id, G, case I of
                                        1 -> Base;
                                        _ -> <<Base/binary, "-", (integer_to_binary(I))/binary>>
                                    end),
    G#{entity => Entity,
       description => avatar_sim_desc:subset(Desc, maps:get(components, G, all), Entity)}.

link_spec(#{entity := Entity, description := Desc} = R, Opts) ->
    Spec = maps:merge(maps:with([endpoints, retry], Opts), maps:with([pairing, credential], R)),
    Spec#{entity => Entity, description => Desc}.

start_world(Model, ModelOpts, Opts) ->
    {ok, Sup} = avatar_sim_sup:start_child(#{start => {avatar_sim_world_sup, start_link, []},
                                             type => supervisor}),
    {ok, Clock} = case maps:get(clock, Opts, #{}) of
                      ClockOpts when is_map(ClockOpts) ->
                          avatar_sim_world_sup:start_clock(Sup, ClockOpts);
                      Clock0 -> {ok, Clock0}
                  end,
    Links = maps:get(links, Opts),
    Args = #{model => Model, model_opts => ModelOpts#{seed => maps:get(seed, Opts, 1)},
             clock => Clock, links => Links},
    {ok, World} = avatar_sim_world_sup:start_world(Sup, Args),
    _ = [{ok, _} = avatar_sim_world_sup:start_link_child(Sup, World, L) || L <- Links],
    {ok, World}.

%% @doc Stops an Avatar: its links say Bye, EVATAR unbinds it.
-spec stop(avatar()) -> ok.
stop(Avatar) ->
    Ref = monitor(process, Avatar),
    ok = gen_statem:stop(Avatar),
    receive {'DOWN', Ref, process, Avatar, _} -> ok end.

%% @doc The world state (docs/avatars.md sections 3.5 and 4.4).
-spec state(avatar()) -> map().
state(Avatar) -> avatar_sim_world:call(Avatar, state).

%% @doc Every signal the Avatar emitted (or would have, had it been
%% connected and bound), oldest first.
-spec log(avatar()) -> [log_entry()].
log(Avatar) -> avatar_sim_world:call(Avatar, log).

%% @doc The Avatar's links to EVATAR.
-spec links(avatar()) -> [map()].
links(Avatar) ->
    [avatar_sim_link:info(Pid)
     || {_, Pid} <- lists:sort(maps:to_list(avatar_sim_world:call(Avatar, links)))].

-spec clock(avatar()) -> clock().
clock(Avatar) -> avatar_sim_world:call(Avatar, clock).

%% @doc Makes a person of the home act now, as a script step would.
-spec act(avatar(), binary(), avatar_sim_script:action()) -> ok | {error, binary()}.
act(Home, Who, Action) -> avatar_sim_world:call(Home, {command, {act, Who, Action}}).

%% @doc Moves the first free ball of that colour (or adds one) to (X, Y).
-spec place_ball(avatar(), binary(), number(), number()) -> ok.
place_ball(Arena, Colour, X, Y) ->
    avatar_sim_world:call(Arena, {command, {place_ball, Colour, X, Y}}).

%% ---------------------------------------------------------------------------
%% Failure hooks
%% ---------------------------------------------------------------------------

%% @doc The device stops answering: requests to it are swallowed.
-spec mute(avatar(), binary()) -> ok | {error, term()}.
mute(Avatar, Component) -> on_component(Avatar, Component, fun(L) ->
                                                                   avatar_sim_link:mute(L, Component, true)
                                                           end).

-spec unmute(avatar(), binary()) -> ok | {error, term()}.
unmute(Avatar, Component) -> on_component(Avatar, Component, fun(L) ->
                                                                     avatar_sim_link:mute(L, Component, false)
                                                             end).

%% @doc The link of entity `EntityId' drops its connection (no Bye) and
%% stays away until {@link reconnect/2}.
-spec disconnect(avatar(), binary()) -> ok | {error, term()}.
disconnect(Avatar, EntityId) -> disconnect(Avatar, EntityId, infinity).

%% @doc As {@link disconnect/2}, coming back by itself after `Ms' real ms.
-spec disconnect(avatar(), binary(), timeout()) -> ok | {error, term()}.
disconnect(Avatar, EntityId, Ms) ->
    on_link(Avatar, EntityId, fun(L) -> avatar_sim_link:disconnect(L, Ms) end).

-spec reconnect(avatar(), binary()) -> ok | {error, term()}.
reconnect(Avatar, EntityId) ->
    on_link(Avatar, EntityId, fun avatar_sim_link:reconnect/1).

%% @doc The device leaves: its gateway describes itself again without it.
-spec detach_device(avatar(), binary()) -> ok | {error, term()}.
detach_device(Avatar, Component) ->
    on_component(Avatar, Component, fun(L) -> avatar_sim_link:detach(L, Component, true) end).

%% @doc The device comes back: its gateway describes itself again with it.
-spec attach_device(avatar(), binary()) -> ok | {error, term()}.
attach_device(Avatar, Component) ->
    on_component(Avatar, Component, fun(L) -> avatar_sim_link:detach(L, Component, false) end).

on_component(Avatar, Component, F) ->
    case avatar_sim_world:call(Avatar, {owner, Component}) of
        {ok, _Entity, Link} -> F(Link);
        {error, _} = Error -> Error
    end.

on_link(Avatar, EntityId, F) ->
    case avatar_sim_world:call(Avatar, {link, EntityId}) of
        {ok, _Entity, Link} -> F(Link);
        {error, _} = Error -> Error
    end.
