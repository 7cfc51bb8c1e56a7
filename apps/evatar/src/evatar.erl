%% @doc Public API of EVATAR, the mediator between Virtual Agents and their
%% Avatars: pairings are created and deleted at run time, entities join one
%% with a credential, describe themselves in BIL and exchange BIL signals
%% routed through the pairing's Body Mapping Registry. Also the operator's
%% inspection functions for a remote shell (`pairings/0', `bindings/1',
%% `registry/1', `stats/1' and their `print_*' forms). docs/architecture.md
%% describes the processes; every other evatar_* module is internal.
-module(evatar).

-export([create_pairing/2, delete_pairing/1, join/4, describe/2, send/2, leave/1,
         session_pid/1, session_info/1]).
-export([pairings/0, bindings/1, registry/1, stats/1,
         print_pairings/0, print_bindings/1, print_registry/1, print_stats/1]).

-export_type([pairing_id/0, role/0, session/0, pairing_opts/0, binding_report/0,
              pairing_summary/0, drop_code/0, session_info/0]).

-record(session, {pairing :: pairing_id(),
                  pid :: pid(),
                  entity :: binary(),
                  role :: role(),
                  join_timeout :: non_neg_integer()}).

-type pairing_id() :: binary().
-type role() :: agent | avatar.
-opaque session() :: #session{}.
%% Timeouts in milliseconds; `join_timeout' and `feedback_timeout' default
%% to 5000, `max_avatars' to 64.
-type pairing_opts() :: #{agent_credential := binary(),
                          avatar_credential := binary(),
                          join_timeout => non_neg_integer(),
                          feedback_timeout => non_neg_integer(),
                          max_avatars => pos_integer()}.
%% Sent to every registered entity after every (re)binding; `entities' are
%% the registered entity ids in registration order.
-type binding_report() :: #{bound := [bil:binding()],
                            unbound := [bil:unbound()],
                            entities := [binary()]}.
%% Why a pairing dropped an entity, in `{evatar, PairingId, {dropped, Code,
%% Reason}}' (Reason is a sentence for a person). A fixed set, so a
%% receiver can map every code: `join_timeout' (no description within the
%% join timeout), `pairing_deleted' (`delete_pairing/1').
-type drop_code() :: join_timeout | pairing_deleted.
-type session_info() :: #{pairing := pairing_id(),
                          entity := binary(),
                          role := role(),
                          pid := pid(),
                          join_timeout := non_neg_integer()}.
-type pairing_summary() :: #{id := pairing_id(),
                             pid := pid(),
                             state := evatar_pairing_logic:phase() | unavailable,
                             atom() => term()}.

-define(CALL_TIMEOUT, 15000).
-define(INSPECT_TIMEOUT, 2000).

%% ---------------------------------------------------------------------------
%% Pairings
%% ---------------------------------------------------------------------------

%% @doc Starts a pairing with its own supervised process tree. Returns the
%% pid of the pairing process.
-spec create_pairing(pairing_id(), pairing_opts()) ->
          {ok, pid()} | {error, already_exists | {bad_option, term()}}.
create_pairing(PairingId, Opts) when is_binary(PairingId) ->
    case evatar_pairing_logic:config(Opts) of
        {ok, Config} ->
            case evatar_registry:whereis_name(PairingId) of
                undefined -> start_pairing(PairingId, Config);
                _Pid -> {error, already_exists}
            end;
        {error, _} = Error ->
            Error
    end;
create_pairing(PairingId, _Opts) ->
    {error, {bad_option, {id, PairingId}}}.

start_pairing(PairingId, Config) ->
    case evatar_pairings_sup:start_pairing(PairingId, Config) of
        {ok, Sup} ->
            [Pid] = [P || {evatar_pairing, P, _, _} <- supervisor:which_children(Sup)],
            {ok, Pid};
        %% Lost a race with another create of the same id.
        {error, {shutdown, {failed_to_start_child, evatar_pairing, {already_started, _}}}} ->
            {error, already_exists}
    end.

%% @doc Stops a pairing and its whole tree. The entities' processes receive
%% `{evatar, PairingId, {dropped, pairing_deleted, Reason}}'. Returns once
%% the pairing process is gone.
-spec delete_pairing(pairing_id()) -> ok | {error, not_found}.
delete_pairing(PairingId) ->
    case evatar_registry:whereis_name(PairingId) of
        undefined ->
            {error, not_found};
        Pid ->
            Ref = erlang:monitor(process, Pid),
            Result = case call(Pid, delete) of
                         ok -> ok;
                         {error, gone} -> {error, not_found}
                     end,
            receive {'DOWN', Ref, process, Pid, _} -> Result end
    end.

%% ---------------------------------------------------------------------------
%% Entities
%% ---------------------------------------------------------------------------

%% @doc Joins pairing `PairingId' as entity `EntityId'. The calling process
%% receives the entity's traffic as `{evatar, PairingId, Message}' and is
%% monitored: its exit is the entity leaving. The caller should monitor
%% {@link session_pid/1}. The entity must describe itself within the
%% pairing's join timeout ({@link session_info/1}) or be dropped.
-spec join(pairing_id(), role(), binary(), binary()) ->
          {ok, session()} |
          {error, unknown_pairing | bad_credential | occupied | entity_exists |
                  too_many_entities}.
join(PairingId, Role, EntityId, Credential)
  when is_binary(PairingId), (Role =:= agent orelse Role =:= avatar),
       is_binary(EntityId), is_binary(Credential) ->
    case evatar_registry:whereis_name(PairingId) of
        undefined ->
            {error, unknown_pairing};
        Pid ->
            case call(Pid, {join, Role, EntityId, Credential, self()}) of
                {ok, JoinTimeout} ->
                    {ok, #session{pairing = PairingId, pid = Pid, entity = EntityId,
                                  role = Role, join_timeout = JoinTimeout}};
                {error, gone} ->
                    {error, unknown_pairing};
                {error, _} = Error ->
                    Error
            end
    end;
join(_PairingId, _Role, _EntityId, _Credential) ->
    {error, bad_credential}.

%% @doc Registers (or replaces) the entity's BIL description; the pairing
%% binds again and reports to every registered entity. Refused with a
%% readable reason when the EntityID is not the joined one, the EntityType
%% does not match the role, or a ComponentID belongs to another entity.
-spec describe(session(), bil:description()) -> ok | {error, binary()}.
describe(#session{pid = Pid, entity = EntityId}, Description) ->
    case call(Pid, {describe, EntityId, Description}) of
        {error, gone} -> {error, <<"the pairing is gone">>};
        Reply -> Reply
    end.

%% @doc Sends a signal (asynchronous). Refusals come back to the entity as
%% BIL error signals; see docs/architecture.md for the routing rules.
-spec send(session(), bil:signal()) -> ok.
send(#session{pid = Pid, entity = EntityId}, Signal) ->
    gen_statem:cast(Pid, {signal, EntityId, Signal}).

%% @doc Leaves the pairing: the entity is unregistered and the pairing binds
%% again. An agent leaving keeps the pairing waiting for a new agent.
-spec leave(session()) -> ok.
leave(#session{pid = Pid, entity = EntityId}) ->
    case call(Pid, {leave, EntityId}) of
        ok -> ok;
        {error, gone} -> ok
    end.

%% @doc The pid of the pairing process the session belongs to.
-spec session_pid(session()) -> pid().
session_pid(#session{pid = Pid}) -> Pid.

%% @doc What a session is about, for logs and the bridge: `join_timeout'
%% is the pairing's, in ms, counted from the join (the bridge reports it in
%% its Welcome).
-spec session_info(session()) -> session_info().
session_info(#session{pairing = P, entity = E, role = R, pid = Pid, join_timeout = J}) ->
    #{pairing => P, entity => E, role => R, pid => Pid, join_timeout => J}.

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
-spec bindings(pairing_id()) -> {ok, binding_report()} | {error, not_found}.
bindings(PairingId) -> inspect(PairingId, bindings).

%% @doc The Service Registration List of a pairing: each joined entity
%% with its role, join time, whether it registered, and its description.
-spec registry(pairing_id()) -> {ok, [map()]} | {error, not_found}.
registry(PairingId) -> inspect(PairingId, registry).

%% @doc Counters of a pairing: signals routed per context, refusals per
%% error code, feedback timeouts, late feedback, requests voided because
%% their provider went, entities dropped, rebinds, pending requests.
-spec stats(pairing_id()) -> {ok, map()} | {error, not_found}.
stats(PairingId) -> inspect(PairingId, stats).

inspect(PairingId, What) ->
    case evatar_registry:whereis_name(PairingId) of
        undefined ->
            {error, not_found};
        Pid ->
            case call(Pid, {inspect, What}) of
                {error, gone} -> {error, not_found};
                Reply -> {ok, Reply}
            end
    end.

%% @doc Prints {@link pairings/0} as a table.
-spec print_pairings() -> ok.
print_pairings() ->
    evatar_print:pairings(pairings()).

%% @doc Prints {@link bindings/1} as a table.
-spec print_bindings(pairing_id()) -> ok | {error, not_found}.
print_bindings(PairingId) ->
    print(bindings(PairingId), fun evatar_print:bindings/1).

%% @doc Prints {@link registry/1} as a table.
-spec print_registry(pairing_id()) -> ok | {error, not_found}.
print_registry(PairingId) ->
    print(registry(PairingId), fun evatar_print:registry/1).

%% @doc Prints {@link stats/1}.
-spec print_stats(pairing_id()) -> ok | {error, not_found}.
print_stats(PairingId) ->
    print(stats(PairingId), fun evatar_print:stats/1).

print({ok, Value}, Printer) -> Printer(Value);
print({error, _} = Error, _Printer) -> Error.

%% A pairing that died between the lookup and the call is a normal race
%% (deleted, or crashed and being restarted), not an error of the caller.
call(Pid, Request) ->
    try
        gen_statem:call(Pid, Request, ?CALL_TIMEOUT)
    catch
        %% The pairing exited before answering (noproc, normal, killed, or
        %% a crash); only a timeout, a pairing alive but stuck, goes on.
        exit:{Reason, {gen_statem, call, _}} when Reason =/= timeout ->
            {error, gone}
    end.
