%% @doc Internal. The cluster's catalogue of pairings: every pairing's id,
%% configuration (credentials as the pairing stores them) and home node, so
%% that pairings survive the loss of every node at once (a power cut) and a
%% node that was away learns what was created and deleted meanwhile.
%%
%% Each node keeps the whole catalogue in a local mnesia table
%% (`disc_copies' when mnesia has a directory, the release's
%% `EVATAR_DATA_DIR'; `ram_copies' otherwise, e.g. `make demo', emptied at
%% every start of evatar). The nodes do not share an mnesia schema: they
%% exchange their entries and merge them with `evatar_catalogue_rules'
%% (versioned entries, tombstones, a deterministic winner), on every write,
%% whenever a peer becomes alive, and every `catalogue_sync_ms'. So nodes
%% that first started apart, a node off for a week, or two sides of a
%% healed partition converge with no operator action
%% (docs/ha-design.md, section 11).
%%
%% A node changes the catalogue (creates, deletes) only while it hears a
%% majority of the configured nodes (evatar_catalogue_rules:may_change/2:
%% a cluster of two also alone); else `{error, no_majority}', and an
%% ensure (a configuration file's pairing, at boot) waits in memory until
%% this node is in sync and hears a majority, then is written if the
%% pairing is still absent. So a change made on a minority side of a
%% partition never beats one made on the majority side.
%%
%% Once this node has exchanged catalogues with every alive peer and hears
%% a majority (in a cluster of two, also after `catalogue_alone_ms' alone),
%% it starts the pairings it owns of which no instance runs anywhere, and
%% stops local instances of deleted ones. Every decision of that look
%% (the reconcile loop: what stops, what is watched, when the node is
%% ready, which waiting ensures are written, what is restored and after
%% what back-off) and of the exchange (which peer gets the whole
%% catalogue when) is taken by evatar_catalogue_rules (look/2,
%% room_checked/4, answered/4; exchange/3, received/3) from what this
%% process read; the process carries out the effects (send the whole
%% catalogue, ask an instance to delete itself, monitor, write and send an
%% entry, start a pairing, log) and answers the rules' two questions (is
%% there room in the data directory, what do the connected peers run).
%% Messages between nodes have the shape `{evatar_catalogue, 1, Body}'
%% (introduced in 0.1.0).
%%
%% A full data directory (evatar_data_dir: no room for
%% `data_dir_reserve_bytes'), found before each change and every
%% `disk_check_ms', is logged as `disk_full' with the directory: the
%% changes asked of this node are refused (`{error, {disk_full, Dir}}'),
%% what peers send is held in memory, and everything runs as before. When
%% there is room again (`disk_space_back') what was held is written
%% (docs/ha.md section 6, "A full disk").
%%
%% Its periodic work (the look every 500 ms, the check of the data
%% directory every `disk_check_ms', the whole catalogue to every alive
%% peer every `catalogue_sync_ms') runs now through {@link
%% reconcile_now/0} (tests, through `evatar:run_now(catalogue)'): each
%% early, deciding as the timed one would.
-module(evatar_catalogue).
-behaviour(gen_server).

-include_lib("kernel/include/logger.hrl").

-export([start_link/0, create/2, remove/2, ensure/2, lookup/1, entries/0, durable/0,
         sync_now/0, reconcile_now/0, disk_full/0]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-define(TABLE, evatar_catalogue).
-define(TICK_MS, 500).
-define(DISK_FULL, {?MODULE, disk_full}).

-record(?TABLE, {id :: evatar:pairing_id(),
                 version :: evatar_catalogue_rules:version(),
                 value :: evatar_catalogue_rules:value()}).

-record(s, {durable :: boolean(),
            %% The data directory when it was found full, and what peers
            %% sent meanwhile (written once there is room).
            full = false :: false | file:filename(),
            held = [] :: [evatar_catalogue_rules:entry()],
            last_disk_check :: integer(),
            %% What the rules remember between looks (the exchange's
            %% peers, pending ensures, back-offs, what ran here, what is
            %% watched).
            memory :: evatar_catalogue_rules:memory()}).

%% @doc Starts the catalogue process, registered as `evatar_catalogue'.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    gen_server:start_link({local, ?MODULE}, ?MODULE, [], []).

%% @doc Starts a new pairing with its active on this node (its home) and
%% records it, telling the alive peers; `already_exists' when the catalogue
%% has it, `no_majority' when this node does not hear a majority of the
%% configured nodes (nothing starts). One at a time with the restores, so
%% neither undoes the other.
-spec create(evatar:pairing_id(), evatar_pairing_logic:config()) ->
          {ok, pid()} | {error, already_exists | no_majority | {disk_full, file:filename()}
                                | term()}.
create(Id, Config) ->
    gen_server:call(?MODULE, {create, Id, Config}, infinity).

%% @doc Records a pairing's deletion (a tombstone), and tells the alive
%% peers, whose instances of it stop. `Running': this node holds an
%% instance of it; the tombstone is then written even when this node's
%% catalogue has no live entry of that id (its creation has not reached
%% this node yet), else the creation would come back later and undo the
%% deletion. `not_found' when the catalogue has no live entry of that id
%% and `Running' is false; `{error, {disk_full, Dir}}' when the deletion
%% cannot be written, `{error, no_majority}' when this node does not hear
%% a majority (nothing is written).
-spec remove(evatar:pairing_id(), Running :: boolean()) ->
          ok | not_found | {error, no_majority | {disk_full, file:filename()}}.
remove(Id, Running) ->
    gen_server:call(?MODULE, {remove, Id, Running}, infinity).

%% @doc Records a pairing unless the catalogue already has it (live):
%% then nothing changes, whatever `Config' says. The pairing is started
%% by the node that owns it once the catalogues are in sync. `pending'
%% when this node does not hear a majority: it is kept in memory and
%% written (unless the pairing exists by then) once this node is in sync
%% with its peers and hears a majority.
-spec ensure(evatar:pairing_id(), evatar_pairing_logic:config()) ->
          created | exists | pending | {error, {disk_full, file:filename()}}.
ensure(Id, Config) ->
    gen_server:call(?MODULE, {ensure, Id, Config}, infinity).

%% @doc A pairing's configuration, when the catalogue has it (live).
-spec lookup(evatar:pairing_id()) -> {ok, evatar_pairing_logic:config()} | none.
lookup(Id) ->
    case mnesia:dirty_read(?TABLE, Id) of
        [#?TABLE{value = {live, Config, _Home}}] -> {ok, Config};
        _ -> none
    end.

%% @doc Every entry, tombstones included, sorted by id.
-spec entries() -> [evatar_catalogue_rules:entry()].
entries() ->
    lists:sort([{Id, V, Val} || {?TABLE, Id, V, Val}
                                    <- mnesia:dirty_match_object(?TABLE, {?TABLE, '_', '_', '_'})]).

%% @doc Whether the catalogue is on disc (survives a restart of this node).
-spec durable() -> boolean().
durable() ->
    gen_server:call(?MODULE, durable, infinity).

%% @doc The data directory when this node found it full (and has not
%% seen room since), else `false'. Free to call: read by the metrics.
-spec disk_full() -> false | file:filename().
disk_full() ->
    persistent_term:get(?DISK_FULL, false).

%% @doc Sends this node's catalogue to every alive peer now.
-spec sync_now() -> ok.
sync_now() ->
    gen_server:cast(?MODULE, sync_now).

%% @doc For tests: this node's periodic work now, as if each of its timers
%% were due (the data directory checked, for room or for room back; the
%% whole catalogue sent to every alive peer; what this node owns and no
%% node runs started, once it is in sync with its peers; local instances
%% of deleted pairings stopped), returning once it is done: what it sent
%% may still be on its way, what it started is starting.
-spec reconcile_now() -> ok.
reconcile_now() ->
    gen_server:call(?MODULE, reconcile_now, infinity).

%% ---------------------------------------------------------------------------
%% gen_server
%% ---------------------------------------------------------------------------

%% @private
-spec init([]) -> {ok, #s{}} | {stop, {data_dir_of_another_node, file:filename(), [node()]}
                                       | {data_dir_unusable, file:filename(), term()}}.
init([]) ->
    case {ensure_data_dir(), foreign_data_dir()} of
        {{error, Dir, Reason}, _} ->
            ?LOG_ERROR(#{what => data_dir_unusable, dir => Dir, reason => Reason,
                         hint => "EVATAR_DATA_DIR cannot be made a directory: give a path this "
                                 "node's user may create (its parents are made as needed)"}),
            {stop, {data_dir_unusable, Dir, Reason}};
        {ok, {Dir, Owners}} ->
            ?LOG_ERROR(#{what => data_dir_of_another_node, dir => Dir, owners => Owners,
                         hint => "EVATAR_DATA_DIR belongs to another node name: give this node "
                                 "its own (an empty directory; it gets the catalogue from the "
                                 "other nodes), or start it under its old name"}),
            {stop, {data_dir_of_another_node, Dir, Owners}};
        {ok, none} ->
            Durable = ensure_storage(),
            self() ! tick,
            Now = now_ms(),
            ?LOG_INFO(#{what => catalogue_opened, durable => Durable, entries => count_live()}),
            persistent_term:put(?DISK_FULL, false),
            {ok, #s{durable = Durable, last_disk_check = Now,
                    memory = evatar_catalogue_rules:new(Now)}}
    end.

ensure_data_dir() ->
    case application:get_env(mnesia, dir) of
        undefined ->
            ok;
        {ok, Dir} ->
            case evatar_data_dir:ensure(Dir) of
                ok -> ok;
                {error, Why} -> {error, Dir, Why}
            end
    end.

%% mnesia's directory keeps the schema of the node that made it. Another
%% node name reads it as a schema of which it holds no copy: its tables
%% would never load here (and the schema cannot be made this node's), so
%% the node says so instead of crashing or waiting for ever.
foreign_data_dir() ->
    case application:get_env(mnesia, dir) of
        undefined ->
            none;
        {ok, Dir} ->
            case mnesia:table_info(schema, disc_copies) of
                [] -> none;
                Owners ->
                    case lists:member(node(), Owners) of
                        true -> none;
                        false -> {Dir, Owners}
                    end
            end
    end.

%% Disc copies when mnesia was given a directory (it then keeps its schema
%% there: made on the first start, read on the next ones). Else an
%% in-memory table that lives as long as evatar does.
ensure_storage() ->
    Disc = application:get_env(mnesia, dir) =/= undefined,
    _ = case Disc andalso mnesia:table_info(schema, storage_type) =:= ram_copies of
            true -> {atomic, ok} = mnesia:change_table_copy_type(schema, node(), disc_copies);
            false -> ok
        end,
    Storage = case Disc of
                  true -> disc_copies;
                  false -> ram_copies
              end,
    {atomic, ok} = case lists:member(?TABLE, mnesia:system_info(tables)) of
                       true ->
                           ok = mnesia:wait_for_tables([?TABLE], infinity),
                           case Disc of
                               true -> {atomic, ok};
                               false -> mnesia:clear_table(?TABLE)
                           end;
                       false ->
                           mnesia:create_table(?TABLE, [{attributes, record_info(fields, ?TABLE)},
                                                        {Storage, [node()]}])
                   end,
    Disc.

%% @private
-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call({create, Id, Config}, _From, S0) ->
    case {lookup(Id), may_change() andalso room(S0)} of
        {{ok, _}, _} ->
            {reply, {error, already_exists}, S0};
        {none, false} ->
            {reply, {error, no_majority}, S0};
        {none, {{error, _} = Full, S}} ->
            {reply, Full, S};
        {none, {ok, S}} ->
            case evatar_pairings_sup:start_pairing(Id, Config) of
                {ok, Sup} ->
                    ok = write_new(Id, {live, Config, node()}, S),
                    {reply, {ok, Sup}, started_here(Id, S)};
                {error, _} = Error ->
                    {reply, Error, S}
            end
    end;
handle_call({remove, Id, Running}, _From, S0) ->
    case {lookup(Id), Running, may_change() andalso room(S0)} of
        {none, false, _} ->
            {reply, not_found, S0};
        {_, _, false} ->
            {reply, {error, no_majority}, S0};
        {_, _, {{error, _} = Full, S}} ->
            {reply, Full, S};
        {_, _, {ok, S}} ->
            ok = write_new(Id, deleted, S),
            {reply, ok, S}
    end;
handle_call({ensure, Id, Config}, _From, S0) ->
    case {lookup(Id), may_change() andalso room(S0)} of
        {{ok, _}, _} ->
            {reply, exists, reconcile(retry(Id, S0))};
        {none, false} ->
            ?LOG_NOTICE(#{what => pairing_ensure_pending, pairing => Id,
                          hint => "this node does not hear a majority of the cluster yet: "
                                  "the pairing is recorded once it does, if still absent"}),
            {reply, pending,
             S0#s{memory = evatar_catalogue_rules:pend(Id, Config, S0#s.memory)}};
        {none, {{error, _} = Full, S}} ->
            {reply, Full, S};
        {none, {ok, S}} ->
            ok = write_new(Id, {live, Config, node()}, S),
            {reply, created, reconcile(retry(Id, S))}
    end;
handle_call(durable, _From, S) ->
    {reply, S#s.durable, S};
handle_call(reconcile_now, _From, S) ->
    {reply, ok, look(S, true)};
handle_call(_Request, _From, S) ->
    {reply, {error, unknown_call}, S}.

%% @private
-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(sync_now, S) ->
    {noreply, run(evatar_catalogue_rules:sync_now(S#s.memory), S)};
handle_cast(_Msg, S) ->
    {noreply, S}.

%% @private
-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info(tick, S) ->
    erlang:send_after(?TICK_MS, self(), tick),
    {noreply, look(S, false)};
handle_info({?MODULE, 1, {entries, From, Entries, Full}}, S0)
  when is_atom(From), is_list(Entries), is_boolean(Full) ->
    Changed = evatar_catalogue_rules:changed(entries(), Entries),
    S = case room(S0) of
            {ok, S2} ->
                ok = write(Changed, S2),
                S2;
            {{error, _}, S2} ->
                _ = [?LOG_NOTICE(#{what => catalogue_held, pairing => Id, from => From,
                                   reason => disk_full}) || {Id, _, _} <- Changed],
                S2#s{held = evatar_catalogue_rules:merge(S2#s.held, Changed)}
        end,
    _ = [?LOG_INFO(#{what => catalogue_learned, pairing => Id, from => From,
                     deleted => Val =:= deleted}) || {Id, _, Val} <- Changed],
    {Effects, M} = evatar_catalogue_rules:received(From, Full, S#s.memory),
    {noreply, reconcile(run(Effects, S#s{memory = M}))};
handle_info({'DOWN', _Ref, process, Pid, Reason}, S) ->
    case evatar_catalogue_rules:down(Pid, Reason, S#s.memory) of
        {true, M} -> {noreply, reconcile(S#s{memory = M})};
        {false, M} -> {noreply, S#s{memory = M}}
    end;
handle_info(_Msg, S) ->
    {noreply, S}.

%% ---------------------------------------------------------------------------
%% Internals
%% ---------------------------------------------------------------------------

%% The periodic work: each part when due, or all now (`Forced').
look(S, Forced) ->
    reconcile(sync(check_disk(S, Forced), Forced)).

write_new(Id, Value, S) ->
    Current = case mnesia:dirty_read(?TABLE, Id) of
                  [#?TABLE{version = V}] -> V;
                  [] -> none
              end,
    publish({Id, evatar_catalogue_rules:next_version(Current, erlang:system_time(millisecond),
                                                     node()), Value}, S).

%% Written here, then sent to the peers alive or connected: one not yet
%% heard (just started) would otherwise learn it only at the next full
%% exchange.
publish(Entry, S) ->
    ok = write([Entry], S),
    _ = [send(N, {entries, node(), [Entry], false})
         || N <- evatar_catalogue_rules:recipients(connected(), S#s.memory)],
    ok.

%% Committed, then the log forced to disc: a pairing the caller was told
%% exists survives a power cut that comes right after.
write([], _S) ->
    ok;
write(Entries, #s{durable = Durable}) ->
    {atomic, ok} = mnesia:sync_transaction(
                     fun() ->
                             lists:foreach(fun({Id, V, Val}) ->
                                                   mnesia:write(#?TABLE{id = Id, version = V,
                                                                        value = Val})
                                           end, Entries)
                     end),
    case Durable of
        true -> mnesia:sync_log();
        false -> ok
    end.

%% Whether a change can be written now: a catalogue in memory always can;
%% on disc, when the data directory has room (evatar_data_dir). Says so
%% when it fills and when there is room again, then writes what was held.
room(#s{durable = false} = S) ->
    {ok, S};
room(#s{full = Was} = S) ->
    {ok, Dir} = application:get_env(mnesia, dir),
    S1 = S#s{last_disk_check = now_ms()},
    case {evatar_data_dir:check(Dir), Was} of
        {ok, false} ->
            {ok, S1};
        {ok, _} ->
            Held = evatar_catalogue_rules:changed(entries(), S#s.held),
            ok = write(Held, S1),
            persistent_term:put(?DISK_FULL, false),
            ?LOG_NOTICE(#{what => disk_space_back, dir => Dir, written => length(Held)}),
            {ok, S1#s{full = false, held = []}};
        {{error, _} = Full, false} ->
            persistent_term:put(?DISK_FULL, Dir),
            ?LOG_ERROR(#{what => disk_full, dir => Dir,
                         reserve_bytes => evatar_data_dir:reserve_bytes(),
                         hint => "EVATAR_DATA_DIR's file system is full: pairings keep running, "
                                 "creating and deleting them is refused until there is room"}),
            {Full, S1#s{full = Dir}};
        {{error, _} = Full, _} ->
            {Full, S1}
    end.

check_disk(#s{durable = true, last_disk_check = Last} = S, Forced) ->
    case Forced orelse now_ms() - Last >= opt(disk_check_ms) of
        true -> element(2, room(S));
        false -> S
    end;
check_disk(S, _Forced) ->
    S.

%% The exchange's round (evatar_catalogue_rules:exchange/3): the whole
%% catalogue to the peers it says.
sync(S, Forced) ->
    {Effects, M} = evatar_catalogue_rules:exchange(
                     #{self => node(), alive => evatar_cluster:alive_nodes(), now_ms => now_ms(),
                       sync_ms => opt(catalogue_sync_ms)}, Forced, S#s.memory),
    run(Effects, S#s{memory = M}).

push(Node) ->
    send(Node, {entries, node(), entries(), true}).

%% Never `nosuspend': a busy distribution buffer would drop the entry.
send(Node, Body) ->
    _ = erlang:send({?MODULE, Node}, {?MODULE, 1, Body}, [noconnect]),
    ok.

%% A look of the reconcile loop (evatar_catalogue_rules:look/2): stops what
%% was deleted, starts what this node owns and nobody runs. Each step's
%% effects are carried out before the next step, which gets what it asked
%% for: the room in the data directory, or what the connected peers run.
reconcile(S) ->
    Facts = facts(),
    step(evatar_catalogue_rules:look(Facts, S#s.memory), Facts, S).

step({Effects, Next, M}, Facts, S0) ->
    S = run(Effects, S0#s{memory = M}),
    case Next of
        done ->
            S;
        room ->
            {Room, S1} = room(S),
            Checked = case Room of
                          ok -> ok;
                          {error, {disk_full, _}} -> full
                      end,
            %% Read again: the room found may have written what was held.
            step(evatar_catalogue_rules:room_checked(Checked, entries(), Facts, S1#s.memory),
                 Facts, S1);
        {ask, Peers, Cont} ->
            Answers = erpc:multicall(Peers, evatar_registry, roles, [], 2000),
            step(evatar_catalogue_rules:answered(Answers, Cont, Facts, S#s.memory), Facts, S)
    end.

facts() ->
    #{self => node(), entries => entries(), roles => evatar_registry:roles(),
      configured => evatar_cluster:configured(), alive => evatar_cluster:alive_nodes(),
      connected => connected(), majority => evatar_cluster:majority_now(),
      size => evatar_cluster:size(), alone_ms => opt(catalogue_alone_ms), now_ms => now_ms(),
      wall_ms => erlang:system_time(millisecond)}.

run(Effects, S) ->
    lists:foldl(fun effect/2, S, Effects).

effect({push, Node}, S) ->
    ok = push(Node),
    S;
effect({delete, Pid}, S) ->
    %% Not from this process: the pairing may take a while.
    _ = spawn(fun() ->
                      try gen_statem:call(Pid, delete, 15000)
                      catch exit:_ -> ok
                      end
              end),
    S;
effect({monitor, Pid}, S) ->
    _ = erlang:monitor(process, Pid),
    S;
effect({write, Entry}, S) ->
    ok = publish(Entry, S),
    S;
effect({restore, Id, Config, RetryAfterMs}, S) ->
    Result = evatar_pairings_sup:start_pairing(Id, Config, restore),
    ?LOG_NOTICE(#{what => pairing_restored, pairing => Id, result => element(1, Result),
                  retry_after_ms => RetryAfterMs}),
    case Result of
        {ok, _} -> started_here(Id, S);
        {error, _} -> S
    end;
effect({log, Level, Report}, S) ->
    ?LOG(Level, Report),
    S.

%% A pairing this node started itself (created or restored here), with
%% its process as found now (evatar_catalogue_rules:started/3).
started_here(Id, S) ->
    {Effects, M} = evatar_catalogue_rules:started(Id, evatar_registry:whereis_name(Id),
                                                  S#s.memory),
    run(Effects, S#s{memory = M}).

retry(Id, S) ->
    S#s{memory = evatar_catalogue_rules:retry(Id, S#s.memory)}.

%% Whether this node may create or delete a pairing now.
may_change() ->
    evatar_catalogue_rules:may_change(evatar_cluster:size(), evatar_cluster:majority_now()).

%% Every configured node connected, alive or not (a suspected node may
%% only be slow, and may still hold an instance).
connected() ->
    Connected = erlang:nodes(),
    [N || N <- evatar_cluster:configured(), lists:member(N, Connected)].

count_live() ->
    length([Id || {Id, _, {live, _, _}} <- entries()]).

now_ms() -> erlang:monotonic_time(millisecond).

%% docs/ha-design.md, section 11.
opt(catalogue_sync_ms) -> application:get_env(evatar, catalogue_sync_ms, 10000);
opt(catalogue_alone_ms) -> application:get_env(evatar, catalogue_alone_ms, 30000);
opt(disk_check_ms) -> application:get_env(evatar, disk_check_ms, 5000).
