%% @doc Internal. The top supervisor of avatar_sim: one temporary child per
%% clock started with `avatar_sim:start_clock/1' and per simulated Avatar
%% (an {@link avatar_sim_world_sup} tree), added and removed at run time.
-module(avatar_sim_sup).
-behaviour(supervisor).

-export([start_link/0, start_child/1]).
-export([init/1]).

-spec start_link() -> {ok, pid()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

%% @doc Starts a temporary child from a child spec without `id' and
%% `restart': the id is made unique, the child is temporary.
-spec start_child(#{start := {module(), atom(), [term()]}, type => worker | supervisor}) ->
          supervisor:startchild_ret().
start_child(Spec) ->
    supervisor:start_child(?MODULE, Spec#{id => make_ref(), restart => temporary}).

-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    {ok, {#{strategy => one_for_one, intensity => 10, period => 10}, []}}.
