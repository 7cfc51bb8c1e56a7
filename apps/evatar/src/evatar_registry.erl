%% @doc Internal. The node-local registry of pairings: pairing id (a binary,
%% never an atom) to the pid of this node's pairing process, usable as a
%% `{via, evatar_registry, PairingId}' name. Writes go through this server,
%% which monitors every registered pid; reads go straight to a protected ETS
%% table, so the hot path (`evatar:join/4', inspection) never waits on it.
%% A dead holder's entry is replaced at once, so a pairing restarted by its
%% supervisor can register before this server has handled the old pid's
%% `DOWN'.
%%
%% It is node-local on purpose: with a standby on another node (issue 5) each
%% node maps a pairing id to its own instance, and which instance is active is
%% decided by the high-availability layer with epochs, not by a cluster-wide
%% name service (`global' resolves a name clash after a partition by killing
%% one side at random, which cannot respect epoch fencing).
%%
%% It also owns a public table of each local instance's role, epoch and
%% peer (its standby, or its active), written by the pairing processes on
%% every role change and read by `evatar_cluster' for inventories. An entry
%% outlives a crashed instance on purpose: the restarted instance finds it
%% and knows it is a restart (its standby may have taken over meanwhile).
-module(evatar_registry).
-behaviour(gen_server).

-export([start_link/0, register_name/2, unregister_name/1, whereis_name/1,
         send/2, all/0, count/0]).
-export([set_role/5, role/1, roles/0, delete_role/2, previous/1]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-define(TABLE, ?MODULE).
-define(ROLES, evatar_ha_role_machine).

%% @doc Starts the registry and creates its table.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    gen_server:start_link({local, ?MODULE}, ?MODULE, [], []).

%% @doc Registers `Pid' under `PairingId'; `no' when a live process holds
%% the name already. A dead holder is replaced: its `DOWN' may still be in
%% flight when a supervisor restarts the pairing.
-spec register_name(evatar:pairing_id(), pid()) -> yes | no.
register_name(PairingId, Pid) when is_binary(PairingId), is_pid(Pid) ->
    gen_server:call(?MODULE, {register, PairingId, Pid}).

%% @doc Removes the name, if any.
-spec unregister_name(evatar:pairing_id()) -> ok.
unregister_name(PairingId) ->
    gen_server:call(?MODULE, {unregister, PairingId}).

%% @doc The live process registered under `PairingId', or `undefined'.
-spec whereis_name(evatar:pairing_id()) -> pid() | undefined.
whereis_name(PairingId) ->
    case ets:lookup(?TABLE, PairingId) of
        [{_, Pid, _Ref}] ->
            case is_process_alive(Pid) of
                true -> Pid;
                false -> undefined
            end;
        [] ->
            undefined
    end.

%% @doc Sends `Msg' to the pairing registered as `PairingId'; exits with
%% `{badarg, {PairingId, Msg}}' when there is none, as the `via' contract asks.
-spec send(evatar:pairing_id(), term()) -> pid().
send(PairingId, Msg) ->
    case whereis_name(PairingId) of
        undefined -> exit({badarg, {PairingId, Msg}});
        Pid -> Pid ! Msg, Pid
    end.

%% @doc Every live registration, sorted by pairing id.
-spec all() -> [{evatar:pairing_id(), pid()}].
all() ->
    lists:sort([{Id, Pid} || {Id, Pid, _} <- ets:tab2list(?TABLE),
                             is_process_alive(Pid)]).

%% @doc The number of registrations (live or about to be cleaned up).
-spec count() -> non_neg_integer().
count() ->
    ets:info(?TABLE, size).

%% ---------------------------------------------------------------------------
%% Roles
%% ---------------------------------------------------------------------------

%% @doc Records the role, epoch and peer of this node's instance `Pid' of
%% pairing `PairingId'.
-spec set_role(evatar:pairing_id(), pid(), atom(), non_neg_integer(), pid() | undefined) -> ok.
set_role(PairingId, Pid, Role, Epoch, Peer) ->
    true = ets:insert(?ROLES, {PairingId, Pid, Role, Epoch, Peer}),
    ok.

%% @doc The role of this node's live instance of `PairingId', as the
%% high-availability messages describe it.
-spec role(evatar:pairing_id()) -> evatar_ha_proto_v1:instance_info().
role(PairingId) ->
    case ets:lookup(?ROLES, PairingId) of
        [{_, Pid, Role, Epoch, Peer}] ->
            case is_process_alive(Pid) of
                true -> #{pid => Pid, role => Role, epoch => Epoch, peer => Peer};
                false -> none
            end;
        [] ->
            none
    end.

%% @doc Every live local instance with its role and epoch (an inventory).
-spec roles() -> [{evatar:pairing_id(), pid(), atom(), non_neg_integer()}].
roles() ->
    [{Id, Pid, Role, Epoch} || {Id, Pid, Role, Epoch, _} <- ets:tab2list(?ROLES),
                               Role =/= starting, is_process_alive(Pid)].

%% @doc Forgets the role entry of `Pid' (an orderly stop).
-spec delete_role(evatar:pairing_id(), pid()) -> ok.
delete_role(PairingId, Pid) ->
    true = ets:match_delete(?ROLES, {PairingId, Pid, '_', '_', '_'}),
    ok.

%% @doc The entry a previous, dead instance of `PairingId' left on this
%% node: `{Role, Epoch}', or `none'.
-spec previous(evatar:pairing_id()) -> {atom(), non_neg_integer()} | none.
previous(PairingId) ->
    case ets:lookup(?ROLES, PairingId) of
        [{_, Pid, Role, Epoch, _}] when Pid =/= self() ->
            case is_process_alive(Pid) of
                true -> none;
                false -> {Role, Epoch}
            end;
        _ ->
            none
    end.

%% ---------------------------------------------------------------------------
%% gen_server
%% ---------------------------------------------------------------------------

%% @private
-spec init([]) -> {ok, #{}}.
init([]) ->
    _ = ets:new(?TABLE, [named_table, protected, set, {read_concurrency, true}]),
    _ = ets:new(?ROLES, [named_table, public, set, {read_concurrency, true}]),
    {ok, #{}}.

%% @private
-spec handle_call(term(), gen_server:from(), #{}) -> {reply, term(), #{}}.
handle_call({register, Id, Pid}, _From, State) ->
    case ets:lookup(?TABLE, Id) of
        [] ->
            {reply, insert(Id, Pid), State};
        [{_, Old, OldRef}] ->
            case is_process_alive(Old) of
                true ->
                    {reply, no, State};
                false ->
                    true = erlang:demonitor(OldRef, [flush]),
                    {reply, insert(Id, Pid), State}
            end
    end;
handle_call({unregister, Id}, _From, State) ->
    case ets:lookup(?TABLE, Id) of
        [{_, _, Ref}] ->
            true = erlang:demonitor(Ref, [flush]),
            true = ets:delete(?TABLE, Id);
        [] ->
            ok
    end,
    {reply, ok, State};
handle_call(_Other, _From, State) ->
    {reply, {error, unknown_call}, State}.

%% @private
-spec handle_cast(term(), #{}) -> {noreply, #{}}.
handle_cast(_Msg, State) ->
    {noreply, State}.

%% @private
-spec handle_info(term(), #{}) -> {noreply, #{}}.
handle_info({'DOWN', Ref, process, Pid, _Reason}, State) ->
    %% Match the whole object: the name may already belong to a successor.
    _ = ets:match_delete(?TABLE, {'_', Pid, Ref}),
    {noreply, State};
handle_info(_Msg, State) ->
    {noreply, State}.

insert(Id, Pid) ->
    Ref = erlang:monitor(process, Pid),
    true = ets:insert(?TABLE, {Id, Pid, Ref}),
    yes.
