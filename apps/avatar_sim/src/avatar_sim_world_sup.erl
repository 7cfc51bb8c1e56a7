%% @doc Internal. The supervisor of one simulated Avatar: its world process
%% (significant: when it stops, for any reason, the whole Avatar goes), its
%% private clock if it has one (significant too), and one link per robot or
%% gateway, restarted alone when it crashes.
-module(avatar_sim_world_sup).
-behaviour(supervisor).

-export([start_link/0, start_clock/2, start_world/2, start_link_child/3]).
-export([init/1]).

-spec start_link() -> {ok, pid()}.
start_link() ->
    supervisor:start_link(?MODULE, []).

-spec start_clock(pid(), avatar_sim_clock:opts()) -> {ok, avatar_sim_clock:clock()}.
start_clock(Sup, Opts) ->
    {ok, _Pid, Clock} = supervisor:start_child(
                          Sup, #{id => clock, start => {avatar_sim_clock, start_link, [Opts]},
                                 restart => temporary, significant => true}),
    {ok, Clock}.

-spec start_world(pid(), avatar_sim_world:args()) -> {ok, pid()} | {error, term()}.
start_world(Sup, Args) ->
    supervisor:start_child(Sup, #{id => world, start => {avatar_sim_world, start_link, [Args]},
                                  restart => temporary, significant => true}).

-spec start_link_child(pid(), pid(), avatar_sim_link:opts()) -> {ok, pid()} | {error, term()}.
start_link_child(Sup, World, #{entity := Entity} = Opts) ->
    supervisor:start_child(Sup, #{id => {link, Entity},
                                  start => {avatar_sim_link, start_link, [World, Opts]},
                                  restart => transient}).

-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    {ok, {#{strategy => one_for_one, intensity => 5, period => 10,
            auto_shutdown => any_significant}, []}}.
