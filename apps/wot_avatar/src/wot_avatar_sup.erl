%% @doc Internal. Supervises the WoT Avatars. Two kinds of child:
%% - started with {@link wot_avatar:start/1}: the Avatar itself, temporary
%%   (a crash is not restarted; start it again once the cause is known);
%% - kept, with {@link wot_avatar:keep/1} or from the `avatars'
%%   application environment (which the node configuration file fills): an
%%   wot_avatar_keeper, which restarts its Avatar with back-off. The keeper
%%   is transient: it ends when its Avatar is stopped on purpose, and is
%%   restarted here only if the keeper itself fails.
-module(wot_avatar_sup).
-behaviour(supervisor).

-export([start_link/0, start_child/1, keep/1, unkeep/1, keepers/0]).
-export([init/1]).

-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

-spec start_child(wot_avatar:opts()) -> {ok, pid()} | {error, term()}.
start_child(Opts) ->
    Spec = #{id => {temporary, make_ref()}, start => {wot_avatar_fsm, start_link, [Opts]},
             restart => temporary, shutdown => 5000, type => worker,
             modules => [wot_avatar_fsm]},
    case supervisor:start_child(?MODULE, Spec) of
        {ok, Pid} -> {ok, Pid};
        {error, _} = Error -> Error
    end.

-spec keep(wot_avatar:opts()) -> {ok, pid()} | {error, already_kept | term()}.
keep(#{entity_id := Entity} = Opts) ->
    case supervisor:start_child(?MODULE, keeper_spec(Opts)) of
        {ok, Pid} ->
            {ok, Pid};
        {error, {already_started, _}} ->
            {error, already_kept};
        {error, already_present} ->
            %% A keeper that ended (its Avatar was stopped): start it over.
            ok = supervisor:delete_child(?MODULE, {kept, Entity}),
            keep(Opts);
        {error, _} = Error ->
            Error
    end.

-spec unkeep(binary()) -> ok | {error, not_found}.
unkeep(Entity) ->
    case supervisor:terminate_child(?MODULE, {kept, Entity}) of
        ok -> supervisor:delete_child(?MODULE, {kept, Entity});
        {error, not_found} -> {error, not_found}
    end.

%% @doc The running keepers, by entity id.
-spec keepers() -> [{binary(), pid()}].
keepers() ->
    [{Entity, Pid} || {{kept, Entity}, Pid, _, _} <- supervisor:which_children(?MODULE),
                      is_pid(Pid)].

-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    Flags = #{strategy => one_for_one, intensity => 10, period => 60},
    {ok, {Flags, [keeper_spec(Opts) || Opts <- application:get_env(wot_avatar, avatars, [])]}}.

keeper_spec(#{entity_id := Entity} = Opts) ->
    #{id => {kept, Entity}, start => {wot_avatar_keeper, start_link, [Opts]},
      restart => transient, shutdown => 20000, type => worker,
      modules => [wot_avatar_keeper]}.
