%% @doc Public API of EVATAR, the mediator between Virtual Agents and their
%% Avatars: pairings are created and deleted at run time, entities join one
%% with a credential, describe themselves in BIL and exchange BIL signals
%% routed through the pairing's Body Mapping Registry. Also the operator's
%% inspection functions for a remote shell (`pairings/0', `bindings/1',
%% `registry/1', `stats/1', `traffic/1' and the `print_*' forms), and the
%% high-availability view (`ha_status/1', `ha_locate/1', `cluster_status/0').
%% For tests, timers fired now: a pairing's (`expire_timer/2') and the
%% node's periodic rounds (`run_now/1').
%% docs/architecture.md describes the processes; every other evatar_* module
%% is internal.
%%
%% The process that joins receives the entity's traffic, exactly:
%% `{evatar, PairingId, {signal, bil:signal()}}',
%% `{evatar, PairingId, {bound, binding_report()}}',
%% `{evatar, PairingId, {dropped, drop_code(), Reason}}' and, for a session
%% of protocol version 2, `{evatar, PairingId, {ack, SignalId}}'. A pairing
%% that crashes sends nothing: its monitor goes `DOWN' (the bridge sends
%% `Refused PairingDown'). A new drop code is an API change: drop_code()
%% and the bridge's mapping to Refused codes (agent_bridge_conn, checked by
%% dialyzer) change together.
%%
%% Calls never hold a caller past its timeout: a pairing is called with
%% `call_timeout' (application env, default 15000 ms), and one that does not
%% answer in time (busy with a large operation, or its node stalled) gives
%% `{error, busy}'. A join is refused `busy' (the bridge sends `Refused
%% Busy', and a join the pairing gets to later ends with that caller's
%% process); a description is refused with a reason saying it stays queued
%% (the Binding report follows when it is applied); inspections return
%% `{error, busy}' (`pairings/0' shows the pairing `unavailable');
%% `delete_pairing/1' returns `{error, busy}' and the deletion happens when
%% the pairing gets to it; `leave_async/1' leaves without waiting (a
%% connection closing on a Bye). agent_bridge_SUITE's group `busy' suspends
%% a real pairing.
-module(evatar).

-export([check_data_dir/0, check_pairing_opts/1, pairing_option_ranges/0, create_pairing/2, ensure_pairing/2, delete_pairing/1, join/4,
         join/5, resume/5, describe/2, leave_async/1,
         send/2, ack/2, report_binding/1, leave/1, session_pid/1, session_info/1]).
-export([pairings/0, bindings/1, registry/1, stats/1, traffic/1,
         print_pairings/0, print_bindings/1, print_registry/1, print_stats/1]).
-export([ha_status/1, ha_locate/1, cluster_status/0, catalogued/0, stored_options/1]).
-export([expire_timer/2, run_now/1]).
-export([hash_credential/1, hash_credential/2, verify_credential/2]).

-export_type([pairing_id/0, role/0, session/0, pairing_opts/0, binding_report/0,
              pairing_summary/0, drop_code/0, session_info/0, join_error/0,
              resume_opts/0, ha_status/0, auth/0, peer_cert/0, identity/0]).

%% A credential as join/4,5 and resume/5 take it: a bare binary, or a map
%% with the client certificate the bridge verified (docs/protocol.md,
%% "TLS"): undefined over plain TCP or when the client presented none.
-define(IS_AUTH(C), (is_binary(C) orelse (is_map(C) andalso is_binary(map_get(credential, C))))).

-record(session, {pairing :: pairing_id(),
                  pid :: pid(),
                  entity :: binary(),
                  role :: role(),
                  join_timeout :: non_neg_integer(),
                  epoch = 1 :: non_neg_integer(),
                  resumed = false :: boolean(),
                  last_accepted = <<>> :: binary(),
                  dedup_window = 0 :: non_neg_integer()}).

-type pairing_id() :: binary().
-type role() :: agent | avatar.
%% A verified client certificate: the SHA-256 of its DER as lowercase hex,
%% and its subject's CommonName (undefined when it has none).
-type peer_cert() :: #{sha256 := binary(), cn := binary() | undefined}.
-type auth() :: binary() | #{credential := binary(), peer_cert := peer_cert() | undefined}.
-opaque session() :: #session{}.
%% Who may join (docs/protocol.md section 7.3): the shared role
%% credentials, a list of `identities' (one per device: its EntityID, role,
%% and its own credential, its client certificate's SHA-256 fingerprint, or
%% both), or both kinds. A listed EntityID joins only with its own
%% identity; an unlisted one is refused unless `unlisted_ids' is
%% `role_credential'. Credentials are given plain or as
%% {@link hash_credential/1} made them; the pairing keeps only hashes.
%% Timeouts in milliseconds; `join_timeout' and `feedback_timeout' default
%% to 5000, `max_avatars' to 64. Limits (docs/protocol.md section 7):
%% `max_id_length' 128 bytes, `max_open_requests' 1024 per requester,
%% `max_consumes' 256 per description, `max_binding_report' 1048576 bytes.
%% High availability (docs/ha-design.md): `resume_timeout',
%% `dedup_window' and `max_unacked_out' default to the application
%% environment's; `standby_node' asks for the standby on that node.
-type pairing_opts() :: #{agent_credential => binary() | evatar_auth:hashed(),
                          avatar_credential => binary() | evatar_auth:hashed(),
                          identities => [identity()],
                          unlisted_ids => refuse | role_credential,
                          max_id_length => pos_integer(),
                          max_open_requests => pos_integer(),
                          max_consumes => pos_integer(),
                          max_binding_report => pos_integer(),
                          join_timeout => non_neg_integer(),
                          feedback_timeout => non_neg_integer(),
                          max_avatars => pos_integer(),
                          resume_timeout => non_neg_integer(),
                          dedup_window => pos_integer(),
                          max_unacked_out => pos_integer(),
                          standby_node => node()}.
%% A session to resume: its id (as given to join/5), the highest Sequence
%% the entity has processed, the highest epoch it has seen.
-type resume_opts() :: #{session := binary(),
                         received := non_neg_integer(),
                         epoch := non_neg_integer()}.
%% One device's identity in `pairing_opts()': `cert_sha256' is the SHA-256
%% fingerprint of its client certificate (hex, colons allowed).
-type identity() :: #{entity := binary(),
                      role := role(),
                      credential => binary() | evatar_auth:hashed(),
                      cert_sha256 => binary()}.
-type join_error() :: unknown_pairing | bad_credential | occupied | entity_exists
                    | too_many_entities | stale_epoch | fenced | {not_active, node()}
                    | busy | id_too_long | reserved_id.
-type ha_status() :: #{role := starting | active | standby | fenced,
                       epoch := non_neg_integer(),
                       node := node(),
                       active := pid() | undefined,
                       standby := pid() | undefined,
                       standby_node := node() | undefined,
                       synced := boolean(),
                       version := non_neg_integer()}.
%% Sent to every registered entity after every (re)binding; `entities' are
%% the registered entity ids in registration order.
-type binding_report() :: #{bound := [bil:binding()],
                            unbound := [bil:unbound()],
                            entities := [binary()]}.
%% Why a pairing dropped an entity, in `{evatar, PairingId, {dropped, Code,
%% Reason}}' (Reason is a sentence for a person). A fixed set, so a
%% receiver can map every code: `join_timeout' (no description within the
%% join timeout), `pairing_deleted' (`delete_pairing/1'), `slow_consumer'
%% (too many delivered signals not acknowledged). The others close the
%% connection but keep the entity in the pairing, for a resume elsewhere:
%% `not_active' (the pairing moved to its standby's node), `fenced' (this
%% node lost the cluster's majority), `stale_epoch' (a newer instance is
%% active), `silent_link' (delivered signals not acknowledged in time),
%% `session_resumed' (the session was resumed on another connection).
-type drop_code() :: join_timeout | pairing_deleted | slow_consumer | not_active | fenced
                   | stale_epoch | silent_link | session_resumed.
-type session_info() :: #{pairing := pairing_id(),
                          entity := binary(),
                          role := role(),
                          pid := pid(),
                          join_timeout := non_neg_integer(),
                          epoch := non_neg_integer(),
                          resumed := boolean(),
                          last_accepted := binary(),
                          dedup_window := non_neg_integer()}.
-type pairing_summary() :: #{id := pairing_id(),
                             pid := pid(),
                             state := evatar_pairing_logic:phase() | standby | fenced
                                    | starting | handing_over | unavailable,
                             atom() => term()}.

%% How long a call waits for a pairing (application env `call_timeout').
-define(CALL_TIMEOUT, 15000).
-define(INSPECT_TIMEOUT, 2000).

%% ---------------------------------------------------------------------------
%% Pairings
%% ---------------------------------------------------------------------------

%% @doc Starts a pairing with its own supervised process tree, its active
%% on this node, and records it in the cluster's catalogue (durable: it
%% comes back after every node restarted, docs/ha.md section 2). Returns
%% the pid of the pairing process. `already_exists' when an alive node runs
%% an instance of that id, or the catalogue has it; `{disk_full, Dir}'
%% when this node's data directory has no room to record it (nothing is
%% started; docs/ha.md section 6, "A full disk"); `no_majority' when this
%% node does not hear a majority of the configured nodes (it is on the
%% minority side of a partition, or most nodes are down: nothing is
%% started; ask a node of the majority, docs/ha.md section 2).
-spec create_pairing(pairing_id(), pairing_opts()) ->
          {ok, pid()} | {error, already_exists | no_majority | {bad_option, term()}
                               | {disk_full, file:filename()}}.
create_pairing(PairingId, Opts) when is_binary(PairingId), is_map(Opts) ->
    case pairing_config(Opts) of
        {ok, Config} ->
            case evatar_registry:whereis_name(PairingId) =:= undefined andalso
                evatar_catalogue:lookup(PairingId) =:= none andalso
                not exists_elsewhere(PairingId) of
                true -> start_pairing(PairingId, Config);
                false -> {error, already_exists}
            end;
        {error, _} = Error ->
            Error
    end;
create_pairing(PairingId, _Opts) ->
    {error, {bad_option, {id, PairingId}}}.

%% @doc Whether this node's data directory (mnesia's `dir',
%% `EVATAR_DATA_DIR') has room for a catalogue change
%% (`data_dir_reserve_bytes', default 1 MiB): `ok', also with no data
%% directory or one not made yet, or `{error, {disk_full, Dir}}'. Needs
%% evatar's code, not its processes: node_config asks it before mnesia
%% starts (docs/ha.md section 6, "A full disk").
-spec check_data_dir() -> ok | {error, {disk_full, file:filename()}}.
check_data_dir() ->
    case application:get_env(mnesia, dir) of
        undefined -> ok;
        {ok, Dir} -> evatar_data_dir:check(Dir)
    end.

%% @doc Pure: checks a pairing's options as create_pairing/2 would, so a
%% configuration file's mistakes are found before the node starts.
-spec check_pairing_opts(term()) -> ok | {error, {bad_option, term()}}.
check_pairing_opts(Opts) ->
    case evatar_pairing_logic:config(Opts) of
        {ok, _} -> ok;
        {error, _} = Error -> Error
    end.

%% @doc Pure: the inclusive range of each numeric pairing option (an
%% integer outside it is `{error, {bad_option, {Key, Value}}}'): timers
%% in ms 0 to 4294967295 (2^32-1, erlang:start_timer/3's limit),
%% max_avatars, max_consumes and max_id_length 1 to 65536, dedup_window,
%% max_unacked_out and max_open_requests 1 to 1048576,
%% max_binding_report 4096 to 268435456 bytes.
-spec pairing_option_ranges() -> #{atom() => {non_neg_integer(), pos_integer()}}.
pairing_option_ranges() ->
    evatar_pairing_logic:option_ranges().

%% @doc Makes sure the cluster has pairing `PairingId': when neither the
%% catalogue nor an alive node has it, records it with `Opts' (its home is
%% this node), and the pairing starts as soon as this node is in sync with
%% the alive nodes and hears a majority (at once on a lone node). When it
%% exists, nothing changes (`exists'), even if `Opts' differ: for a node's
%% configuration file, read at every start, that lists pairings to create
%% when absent. `pending' when this node does not hear a majority yet
%% (a node of a larger cluster booting first): the pairing is recorded
%% once it does and has the others' catalogues, unless it exists by then.
%% Options are checked as by {@link create_pairing/2}; `{disk_full, Dir}'
%% as there.
-spec ensure_pairing(pairing_id(), pairing_opts()) ->
          {ok, created | exists | pending}
          | {error, {bad_option, term()} | {disk_full, file:filename()}}.
ensure_pairing(PairingId, Opts) when is_binary(PairingId), is_map(Opts) ->
    case pairing_config(Opts) of
        {ok, Config} ->
            case evatar_registry:whereis_name(PairingId) =:= undefined andalso
                not exists_elsewhere(PairingId) of
                true ->
                    case evatar_catalogue:ensure(PairingId, Config) of
                        {error, _} = Full -> Full;
                        Done -> {ok, Done}
                    end;
                false -> {ok, exists}
            end;
        {error, _} = Error ->
            Error
    end;
ensure_pairing(PairingId, _Opts) ->
    {error, {bad_option, {id, PairingId}}}.

pairing_config(Opts) ->
    Defaults = maps:from_list([{K, evatar_cluster:opt(K)}
                               || K <- [resume_timeout, dedup_window, max_unacked_out]]),
    evatar_pairing_logic:config(maps:merge(Defaults, Opts)).

%% With a cluster, a pairing id is unique across the nodes alive.
exists_elsewhere(PairingId) ->
    case [N || N <- evatar_cluster:alive_nodes(), N =/= node()] of
        [] ->
            false;
        Peers ->
            lists:any(fun({ok, #{}}) -> true;
                         (_) -> false
                      end, erpc:multicall(Peers, evatar_registry, role, [PairingId], 2000))
    end.

start_pairing(PairingId, Config) ->
    case evatar_catalogue:create(PairingId, Config) of
        {ok, Sup} ->
            [Pid] = [P || {evatar_pairing, P, _, _} <- supervisor:which_children(Sup)],
            {ok, Pid};
        {error, already_exists} ->
            {error, already_exists};
        {error, {disk_full, _}} = Full ->
            Full;
        {error, no_majority} = No ->
            No;
        %% Lost a race with another create of the same id.
        {error, {shutdown, {failed_to_start_child, evatar_pairing, {already_started, _}}}} ->
            {error, already_exists}
    end.

%% @doc Deletes a pairing: records its deletion in the catalogue (every
%% node stops its instances, now or when it comes back) and stops its
%% tree. The entities' processes receive `{evatar, PairingId, {dropped,
%% pairing_deleted, Reason}}'. When this node holds an instance, returns
%% once the pairing process is gone.
%% `{error, busy}' when the pairing did not answer within the call timeout
%% (application env `call_timeout', default 15 s: it is working through a
%% large operation); the request stays queued, so the pairing goes once it
%% gets to it (and the deletion is recorded already).
%% `{error, {disk_full, Dir}}' when this node's data directory has no room
%% to record the deletion: nothing stops. `{error, no_majority}' when this
%% node does not hear a majority of the configured nodes: nothing stops
%% (ask a node of the majority).
-spec delete_pairing(pairing_id()) ->
          ok | {error, not_found | busy | no_majority | {disk_full, file:filename()}}.
delete_pairing(PairingId) ->
    Target = case evatar_registry:role(PairingId) of
                 %% Deleting through the standby's node deletes at the active.
                 #{role := standby, peer := Active} when is_pid(Active) -> Active;
                 _ -> evatar_registry:whereis_name(PairingId)
             end,
    %% An instance here is proof the pairing exists, even when its
    %% catalogue entry has not reached this node yet: the deletion is
    %% recorded all the same, so that entry cannot bring it back.
    Catalogued = evatar_catalogue:remove(PairingId, Target =/= undefined),
    case {Target, Catalogued} of
        {_, {error, _} = Refused} ->
            Refused;
        {undefined, ok} ->
            ok;
        {undefined, not_found} ->
            {error, not_found};
        {Pid, _} ->
            Ref = erlang:monitor(process, Pid),
            case {call(Pid, delete), Catalogued} of
                {ok, _} ->
                    receive {'DOWN', Ref, process, Pid, _} -> ok end;
                {{error, gone}, ok} ->
                    receive {'DOWN', Ref, process, Pid, _} -> ok end;
                {{error, gone}, not_found} ->
                    receive {'DOWN', Ref, process, Pid, _} -> {error, not_found} end;
                {{error, busy}, _} ->
                    true = erlang:demonitor(Ref, [flush]),
                    {error, busy}
            end
    end.

%% ---------------------------------------------------------------------------
%% Entities
%% ---------------------------------------------------------------------------

%% @doc Joins pairing `PairingId' as entity `EntityId'. The calling process
%% receives the entity's traffic as `{evatar, PairingId, Message}' and is
%% monitored: its exit is the entity leaving. The caller should monitor
%% {@link session_pid/1}. The entity must describe itself within the
%% pairing's join timeout ({@link session_info/1}) or be dropped.
%% On a node holding only the standby the answer is `{not_active, Node}'
%% (Node runs the active); on a fenced one, `fenced'; `busy' when the
%% pairing did not answer within the call timeout (the caller is not held longer, and
%% a join the pairing gets to later ends when the caller's process does).
-spec join(pairing_id(), role(), binary(), auth()) -> {ok, session()} | {error, join_error()}.
join(PairingId, Role, EntityId, Auth)
  when is_binary(PairingId), (Role =:= agent orelse Role =:= avatar),
       is_binary(EntityId), ?IS_AUTH(Auth) ->
    join_call(PairingId, EntityId, Role, Auth,
              fun(Verdict) -> {join, Role, EntityId, Verdict, self()} end);
join(_PairingId, _Role, _EntityId, _Credential) ->
    {error, bad_credential}.

%% @doc Joins with a high-availability session (protocol version 2): the
%% pairing keeps the entity for `resume_timeout' ms when the caller goes,
%% de-duplicates its signals by SignalID, acknowledges each accepted signal
%% with `{evatar, PairingId, {ack, SignalId}}' (after its standby has it)
%% and keeps what it delivers until {@link ack/2}.
-spec join(pairing_id(), role(), binary(), auth(), #{session := binary()}) ->
          {ok, session()} | {error, join_error()}.
join(PairingId, Role, EntityId, Auth, #{session := S} = Opts)
  when is_binary(PairingId), (Role =:= agent orelse Role =:= avatar),
       is_binary(EntityId), ?IS_AUTH(Auth), is_binary(S) ->
    join_call(PairingId, EntityId, Role, Auth,
              fun(Verdict) -> {join, Role, EntityId, Verdict, self(), Opts} end);
join(_PairingId, _Role, _EntityId, _Credential, _Opts) ->
    {error, bad_credential}.

%% @doc Resumes a high-availability session after a reconnect or a takeover:
%% the calling process becomes the entity's, and what was delivered after
%% `received' is delivered again. An unknown session is a fresh join
%% (`resumed' false in {@link session_info/1}). `stale_epoch' when the
%% caller has seen a newer epoch than this instance's.
-spec resume(pairing_id(), role(), binary(), auth(), resume_opts()) ->
          {ok, session()} | {error, join_error()}.
resume(PairingId, Role, EntityId, Auth,
       #{session := S, received := R, epoch := E} = Opts)
  when is_binary(PairingId), (Role =:= agent orelse Role =:= avatar),
       is_binary(EntityId), ?IS_AUTH(Auth), is_binary(S), is_integer(R), R >= 0,
       is_integer(E), E >= 0 ->
    join_call(PairingId, EntityId, Role, Auth,
              fun(Verdict) -> {resume, Role, EntityId, Verdict, self(), Opts} end);
resume(_PairingId, _Role, _EntityId, _Credential, _Opts) ->
    {error, bad_credential}.

%% The credential is checked here, in the caller's process, against what
%% the pairing requires of this EntityID (a hash, a certificate
%% fingerprint): the PBKDF2 cost is the joining client's, and only the
%% verdict reaches the pairing.
join_call(PairingId, EntityId, Role, Auth, Request) ->
    Result = join_call1(PairingId, EntityId, Role, Auth, Request),
    ok = count_join(Role, Request, Result),
    Result.

count_join(Role, Request, {ok, _}) ->
    Kind = case {Role, element(1, Request(authenticated))} of
               {agent, join} -> agent_join;
               {avatar, join} -> avatar_join;
               {agent, resume} -> agent_resume;
               {avatar, resume} -> avatar_resume
           end,
    evatar_metrics:inc(evatar_joins_total, Kind);
count_join(_Role, _Request, {error, {not_active, _}}) ->
    evatar_metrics:inc(evatar_join_refusals_total, not_active);
count_join(_Role, _Request, {error, Reason}) ->
    evatar_metrics:inc(evatar_join_refusals_total, Reason).

join_call1(PairingId, EntityId, Role, Auth, Request) ->
    case evatar_registry:whereis_name(PairingId) of
        undefined ->
            {error, unknown_pairing};
        Pid ->
            case call(Pid, {auth, Role, EntityId}) of
                {ok, Requirement} ->
                    join_verified(Pid, PairingId, EntityId, Role,
                                  Request(evatar_auth:verify(Requirement, Auth)));
                {error, gone} ->
                    {error, unknown_pairing};
                {error, _} = Error ->
                    Error
            end
    end.

join_verified(Pid, PairingId, EntityId, Role, Request) ->
    case call(Pid, Request) of
        {ok, #{join_timeout := J, epoch := E, resumed := R, last_accepted := L,
               dedup_window := W}} ->
            {ok, #session{pairing = PairingId, pid = Pid, entity = EntityId,
                          role = Role, join_timeout = J, epoch = E, resumed = R,
                          last_accepted = L, dedup_window = W}};
        {error, gone} ->
            {error, unknown_pairing};
        {error, _} = Error ->
            Error
    end.

%% @doc Registers (or replaces) the entity's BIL description; the pairing
%% binds again and reports to every registered entity. Refused with a
%% readable reason when the EntityID is not the joined one, the EntityType
%% does not match the role, or a ComponentID belongs to another entity.
%% A pairing that does not answer within the call timeout gives a reason saying so:
%% the description stays queued, and the binding report follows when the
%% pairing applies it.
-spec describe(session(), bil:description()) -> ok | {error, binary()}.
describe(#session{pid = Pid, entity = EntityId}, Description) ->
    case call(Pid, {describe, EntityId, Description}) of
        {error, gone} -> {error, <<"the pairing is gone">>};
        {error, busy} ->
            {error, iolist_to_binary(
                      io_lib:format("the pairing did not answer within ~b ms (busy); the "
                                    "description stays queued and a binding report follows "
                                    "when it is applied", [call_timeout()]))};
        Reply -> Reply
    end.

%% @doc Sends a signal (asynchronous). Refusals come back to the entity as
%% BIL error signals; see docs/architecture.md for the routing rules.
-spec send(session(), bil:signal()) -> ok.
send(#session{pid = Pid, entity = EntityId}, Signal) ->
    gen_statem:cast(Pid, {signal, EntityId, Signal}).

%% @doc Asks for the pairing's current Binding report (asynchronous): it
%% comes to the session's process as `{evatar, Pairing, {bound, Report}}',
%% in order with the reports of rebindings (docs/protocol.md, GetBinding).
-spec report_binding(session()) -> ok.
report_binding(#session{pid = Pid, entity = EntityId}) ->
    gen_statem:cast(Pid, {report_binding, EntityId}).

%% @doc Acknowledges every signal delivered to a high-availability session
%% up to Sequence `Seq' (asynchronous, cumulative): the pairing forgets them.
-spec ack(session(), non_neg_integer()) -> ok.
ack(#session{pid = Pid, entity = EntityId}, Seq) when is_integer(Seq), Seq >= 0 ->
    gen_statem:cast(Pid, {client_ack, EntityId, Seq}).

%% @doc Leaves the pairing: the entity is unregistered and the pairing binds
%% again. An agent leaving keeps the pairing waiting for a new agent.
%% Returns once the pairing has done it, or after the call timeout if it is busy: the
%% Leave is then queued and done when the pairing gets to it.
-spec leave(session()) -> ok.
leave(#session{pid = Pid, entity = EntityId}) ->
    case call(Pid, {leave, EntityId}) of
        ok -> ok;
        {error, gone} -> ok;
        {error, busy} -> ok
    end.

%% @doc Leaves the pairing without waiting: for a process about to end
%% (a connection closing on a Bye), which needs no answer and must not be
%% held by a busy pairing. Sent before the process exits, the Leave
%% reaches the pairing before the exit does.
-spec leave_async(session()) -> ok.
leave_async(#session{pid = Pid, entity = EntityId}) ->
    gen_statem:cast(Pid, {leave, EntityId}).

%% @doc A credential's stored form for pairing options (PBKDF2-HMAC-SHA256,
%% 1,000 iterations, a random 16-byte salt): keep this in configuration
%% instead of the plain credential.
-spec hash_credential(binary()) -> evatar_auth:hashed().
hash_credential(Plain) when is_binary(Plain) -> evatar_auth:hash(Plain).

%% @doc {@link hash_credential/1} with another iteration count.
-spec hash_credential(binary(), pos_integer()) -> evatar_auth:hashed().
hash_credential(Plain, Iterations) when is_binary(Plain) -> evatar_auth:hash(Plain, Iterations).

%% @doc Whether `Plain' is the credential `Stored' (as {@link
%% hash_credential/1} made it) was made from; compared in constant time.
%% For other secrets kept the same way (the HTTP API's operator token).
-spec verify_credential(evatar_auth:hashed(), binary()) -> boolean().
verify_credential(Stored, Plain) when is_binary(Plain) ->
    evatar_auth:verify(#{credential => Stored}, Plain) =:= authenticated.

%% @doc The pid of the pairing process the session belongs to.
-spec session_pid(session()) -> pid().
session_pid(#session{pid = Pid}) -> Pid.

%% @doc What a session is about, for logs and the bridge: `join_timeout'
%% is the pairing's, in ms, counted from the join (the bridge reports it in
%% its Welcome).
-spec session_info(session()) -> session_info().
session_info(#session{pairing = P, entity = E, role = R, pid = Pid, join_timeout = J,
                      epoch = Ep, resumed = Res, last_accepted = L, dedup_window = W}) ->
    #{pairing => P, entity => E, role => R, pid => Pid, join_timeout => J, epoch => Ep,
      resumed => Res, last_accepted => L, dedup_window => W}.

%% ---------------------------------------------------------------------------
%% Inspection
%% ---------------------------------------------------------------------------

%% @doc Every pairing of this node, sorted by id, with its state, agent,
%% number of avatars, registered entities, bound and unbound entries and
%% pending requests. A pairing too busy to answer shows `unavailable'.
-spec pairings() -> [pairing_summary()].
pairings() ->
    [summary(Id, Pid) || {Id, Pid} <- evatar_registry:all()].

summary(Id, Pid) ->
    try gen_statem:call(Pid, {inspect, summary}, ?INSPECT_TIMEOUT) of
        Summary -> Summary#{id => Id}
    catch
        exit:_ -> #{id => Id, pid => Pid, state => unavailable}
    end.

%% @doc The Body Mapping Registry of a pairing: bound and unbound entries.
-spec bindings(pairing_id()) -> {ok, binding_report()} | {error, not_found | busy}.
bindings(PairingId) -> inspect(PairingId, bindings).

%% @doc The Service Registration List of a pairing: each joined entity
%% with its role, join time, whether it registered, and its description.
-spec registry(pairing_id()) -> {ok, [map()]} | {error, not_found | busy}.
registry(PairingId) -> inspect(PairingId, registry).

%% @doc Counters of a pairing: signals routed per context, refusals per
%% error code, feedback timeouts, late feedback, requests voided because
%% their provider went, entities dropped, rebinds, pending requests.
%% Like every inspection, `{error, busy}' when the pairing did not answer
%% within the call timeout.
-spec stats(pairing_id()) -> {ok, map()} | {error, not_found | busy}.
stats(PairingId) -> inspect(PairingId, stats).

%% @doc How many signals each joined entity has sent the pairing and been
%% delivered by it (its Sequence), and how many requests are open
%% (evatar_pairing_logic:traffic/1): a simulation that also counts what its
%% entities sent and handled knows from it when nothing is in flight. A
%% cheap read: no description is copied.
-spec traffic(pairing_id()) -> {ok, evatar_pairing_logic:traffic()} | {error, not_found | busy}.
traffic(PairingId) -> inspect(PairingId, traffic).

inspect(PairingId, What) ->
    case evatar_registry:whereis_name(PairingId) of
        undefined ->
            {error, not_found};
        Pid ->
            case call(Pid, {inspect, What}) of
                {error, gone} -> {error, not_found};
                {error, busy} -> {error, busy};
                Reply -> {ok, Reply}
            end
    end.

%% @doc For tests: fires this node's instance's timer Key now, as if it
%% had expired (`{feedback, Component, SignalId}', `{join, EntityId}',
%% `{resume, EntityId}': evatar_pairing_logic:timer_key()), so that a case
%% checks what the timeout does without a short timeout that a loaded
%% machine could reach early or late elsewhere in the case. The timer is
%% cancelled and its expiry handled as the real one would be (after what
%% the pairing received before this call); `{error, no_timer}' when no
%% such timer is running (never armed, already expired or cancelled).
-spec expire_timer(pairing_id(), evatar_pairing_logic:timer_key()) ->
          ok | {error, no_timer | not_found | busy}.
expire_timer(PairingId, Key) ->
    case evatar_registry:whereis_name(PairingId) of
        undefined ->
            {error, not_found};
        Pid ->
            case call(Pid, {expire_timer, Key}) of
                {error, gone} -> {error, not_found};
                Reply -> Reply
            end
    end.

%% @doc For tests: one round of this node's periodic work now, as its
%% timer would run it, returning once the round is done, so that a case
%% fires the round whose decision it checks instead of waiting for it:
%% `cluster' (the membership's evaluation, every `heartbeat_ms': who is
%% alive, the majority), `catalogue' (the catalogue's periodic work, as if
%% all of it were due: the data directory checked, the whole catalogue
%% sent to every alive peer, pairings this node owns and no node runs
%% started, deleted ones stopped), `rebalancer' (a
%% rebalancing round, whatever `rebalance_delay_ms' and
%% `rebalance_round_ms' say: on the coordinator, the moves it sent, `[]'
%% once the placement is even; elsewhere why not,
%% `{error, {not_coordinator, Node}}' naming the coordinator). An early
%% round decides what the timed one would have: safe on a running node.
%% What a round sent to other nodes or to pairings may still be on its way.
-spec run_now(cluster | catalogue) -> ok;
             (rebalancer) -> evatar_rebalancer:round().
run_now(cluster) -> evatar_cluster:refresh_now();
run_now(catalogue) -> evatar_catalogue:reconcile_now();
run_now(rebalancer) -> evatar_rebalancer:plan_now().

%% ---------------------------------------------------------------------------
%% High availability
%% ---------------------------------------------------------------------------

%% @doc The role of this node's instance of a pairing: `active' (with its
%% standby, and `synced' once the standby confirmed the state), `standby'
%% (with its active), `fenced', or `starting'; its epoch and the number of
%% replicated events applied (`version').
-spec ha_status(pairing_id()) -> {ok, ha_status()} | {error, not_found | busy}.
ha_status(PairingId) -> inspect(PairingId, ha).

%% @doc Every instance of a pairing on the cluster's alive nodes.
-spec ha_locate(pairing_id()) -> [{node(), ha_status()}].
ha_locate(PairingId) ->
    Nodes = lists:sort(evatar_cluster:alive_nodes()),
    Results = erpc:multicall(Nodes, ?MODULE, ha_status, [PairingId], 2000),
    [{N, Status} || {N, {ok, {ok, Status}}} <- lists:zip(Nodes, Results)].

%% @doc The cluster as this node sees it: the configured nodes, those alive
%% (connected and heard recently), those suspected, and whether a majority
%% is heard within the lease.
-spec cluster_status() -> #{configured := [node()], up := [node()], suspected := [node()],
                            quorum := boolean()}.
cluster_status() -> evatar_cluster:status().

%% @doc The ids of the pairings the cluster's catalogue has (as this node
%% knows it), running or not, sorted.
-spec catalogued() -> [pairing_id()].
catalogued() ->
    [Id || {Id, _Version, {live, _, _}} <- evatar_catalogue:entries()].

%% @doc The options a pairing was created with, as the cluster's catalogue
%% keeps them: defaults filled in, credentials only as hashes.
-spec stored_options(pairing_id()) -> {ok, pairing_opts()} | {error, not_found}.
stored_options(PairingId) ->
    case evatar_catalogue:lookup(PairingId) of
        {ok, Config} -> {ok, Config};
        none -> {error, not_found}
    end.

%% @doc Prints {@link pairings/0} as a table.
-spec print_pairings() -> ok.
print_pairings() ->
    evatar_print:pairings(pairings()).

%% @doc Prints {@link bindings/1} as a table.
-spec print_bindings(pairing_id()) -> ok | {error, not_found | busy}.
print_bindings(PairingId) ->
    print(bindings(PairingId), fun evatar_print:bindings/1).

%% @doc Prints {@link registry/1} as a table.
-spec print_registry(pairing_id()) -> ok | {error, not_found | busy}.
print_registry(PairingId) ->
    print(registry(PairingId), fun evatar_print:registry/1).

%% @doc Prints {@link stats/1}.
-spec print_stats(pairing_id()) -> ok | {error, not_found | busy}.
print_stats(PairingId) ->
    print(stats(PairingId), fun evatar_print:stats/1).

print({ok, Value}, Printer) -> Printer(Value);
print({error, _} = Error, _Printer) -> Error.

call_timeout() ->
    application:get_env(evatar, call_timeout, ?CALL_TIMEOUT).

%% A pairing that died between the lookup and the call is a normal race
%% (deleted, or crashed and being restarted), not an error of the caller.
%% One alive but not answering within the call timeout (a large operation,
%% a stalled node) is `busy': the caller, often a connection process, goes
%% on with an answer it can pass on instead of crashing. The request stays
%% in the pairing's queue; its late reply is dropped (gen_statem aliases).
call(Pid, Request) ->
    try
        gen_statem:call(Pid, Request, call_timeout())
    catch
        exit:{timeout, {gen_statem, call, _}} ->
            {error, busy};
        exit:{_Reason, {gen_statem, call, _}} ->
            {error, gone}
    end.
