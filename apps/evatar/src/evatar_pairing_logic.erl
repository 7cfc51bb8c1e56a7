%% @doc Internal. The whole decision logic of one pairing, pure: the state is
%% one value (Service Registration List, Body Mapping Registry with its
%% routing index, pending requests with absolute deadlines, per-entity
%% sequence numbers, counters, epoch) and {@link handle/3} maps an event to
%% the new state and a list of effects, which are data (send a message,
%% start a timer, log): `evatar_ha_instance' holds this state and runs its
%% effects through the output commit, and `evatar_pairing' executes them.
%%
%% Nothing here holds a pid, a monitor or a timer reference, and time comes
%% in as an argument: this value is what a standby holds (the active ships
%% every event with its time; the standby applies it here and keeps the
%% state, discarding the effects), and a standby taking over re-arms the
%% timers from {@link timers/2}. Entities are known by their entity ids; the
%% process maps them to pids.
%%
%% High availability (docs/ha-design.md) adds, for entities
%% joined with a session id (protocol version 2): a bounded window of the
%% SignalIDs already accepted from them (a resent signal is acknowledged,
%% not routed again), the signals delivered to them and not yet acknowledged
%% (re-delivered on resume, bounded: SlowConsumer beyond), and detachment: an
%% entity whose connection went, or every entity after a takeover, is kept
%% for `resume_timeout' ms for a Resume.
%%
%% Registration: a description is refused (with a reason) when its
%% EntityID is not the joined one, its EntityType does not match the role,
%% or a ComponentID is another entity's; else it replaces the entity's
%% registration and the pairing binds again (`bil:bind/1') over the
%% registered descriptions in registration order, the order of each
%% entity's first description (re-describing keeps an entity's place, so a
%% replaced device does not reshuffle ties), and every registered entity
%% gets a Binding report. The phase is `bound' once an agent and an Avatar
%% have registered, `waiting' otherwise; the agent leaving keeps the
%% pairing, waiting for a new agent. Delivered signals get a Sequence per
%% receiving entity (EVATAR's own signals counted) and the epoch.
%% `request_no_feedback', `sensor_data' and `event' open no pending entry
%% and no timer: a sensor stream costs two map lookups, two counters (the
%% routed context and the sender's `received', traffic/1) and the
%% stamp per signal. Every event costs at most n log n in the pairing's
%% open requests, entities and components (bench/COMPLEXITY.md); voiding
%% the open requests of a provider that went gathers their effects in one
%% pass (appending per request, 15,000 requests once stalled a pairing for
%% 14 to 27 s). What a client sees of these rules is docs/protocol.md sections 4
%% to 6.
-module(evatar_pairing_logic).

-export([config/1, option_ranges/0, new/2, handle/3]).
-export([phase/1, summary/1, bindings/1, registration_list/1, stats/1, traffic/1,
         timers/2, pairing_id/1, epoch/1, entity_ids/1, config_of/1,
         unacked_since/1, attached_ids/1, last_accepted/2, accepted_ids/2, unacked/2]).

-export_type([state/0, config/0, event/0, effect/0, timer_key/0, phase/0, traffic/0]).

-define(MEDIATOR, <<"EVATAR">>).

-record(entity, {id :: binary(),
                 role :: evatar:role(),
                 joined_at :: integer(),
                 join_deadline :: integer(),
                 description = undefined :: bil:description() | undefined,
                 seq = 0 :: non_neg_integer(),
                 %% HA sessions only (undefined session: protocol version 1).
                 session = undefined :: binary() | undefined,
                 attached = true :: boolean(),
                 resume_deadline = undefined :: integer() | undefined,
                 %% SignalIDs accepted, newest last, at most dedup_window.
                 seen = #{} :: #{binary() => true},
                 seen_q = queue:new() :: queue:queue(binary()),
                 last_accepted = <<>> :: binary(),
                 %% Delivered, not yet acknowledged: {Seq, Signal, DeliveredAt}.
                 out = queue:new() :: queue:queue({pos_integer(), bil:signal(), integer()}),
                 outn = 0 :: non_neg_integer()}).

%% An open `request': who asked whom, and until when the answer may come.
-record(pending, {requester :: binary(),          % entity id
                  provider :: binary(),           % component id
                  provider_entity :: binary(),
                  deadline :: integer()}).

-record(st, {id :: evatar:pairing_id(),
             config :: config(),
             epoch = 1 :: pos_integer(),
             entities = #{} :: #{binary() => #entity{}},
             agent = undefined :: binary() | undefined,
             avatars = 0 :: non_neg_integer(),
             %% Described entities in registration order (first description).
             order = [] :: [binary()],
             %% ComponentID -> entity id, over every registered description.
             components = #{} :: #{binary() => binary()},
             bound = [] :: [bil:binding()],
             unbound = [] :: [bil:unbound()],
             %% {Sender, Receiver} component pairs allowed to talk.
             routes = #{} :: #{{binary(), binary()} => forward | reverse},
             %% Keyed by {requester ComponentID, request SignalID}.
             pending = #{} :: #{{binary(), binary()} => #pending{}},
             counters = #{} :: #{term() => non_neg_integer()},
             next_id = 1 :: pos_integer(),
             %% HA entities over max_unacked_out during the current event.
             overflow = [] :: [binary()],
             %% Open requests per requester entity (max_open_requests).
             open = #{} :: #{binary() => pos_integer()},
             %% Bytes each registered entity may add to a Binding report at
             %% most, and their sum (max_binding_report).
             charges = #{} :: #{binary() => non_neg_integer()},
             charged = 0 :: non_neg_integer()}).

-opaque state() :: #st{}.
%% Credentials are stored hashed (evatar_auth); see evatar:pairing_opts().
-type config() :: #{agent_credential => evatar_auth:hashed(),
                    avatar_credential => evatar_auth:hashed(),
                    identities => [evatar_auth:identity()],
                    unlisted_ids => refuse | role_credential,
                    max_id_length := pos_integer(),
                    max_open_requests := pos_integer(),
                    max_consumes := pos_integer(),
                    max_binding_report := pos_integer(),
                    join_timeout := non_neg_integer(),
                    feedback_timeout := non_neg_integer(),
                    max_avatars := pos_integer(),
                    resume_timeout := non_neg_integer(),
                    dedup_window := pos_integer(),
                    max_unacked_out := pos_integer(),
                    standby_node => node()}.
-type timer_key() :: {join, EntityId :: binary()}
                   | {feedback, RequesterComponent :: binary(), SignalId :: binary()}
                   | {resume, EntityId :: binary()}.
%% A join carries the verdict of evatar_auth:verify/2, made before the event
%% (the pairing process never sees a plain credential); a plain credential
%% is verified here, for tests and direct use of this module.
-type auth() :: evatar_auth:verdict() | evatar:auth().
-type event() :: {join, evatar:role(), EntityId :: binary(), auth()}
               | {join, evatar:role(), EntityId :: binary(), auth(),
                  SessionId :: binary()}
               | {resume, evatar:role(), EntityId :: binary(), auth(),
                  SessionId :: binary(), Received :: non_neg_integer(),
                  ClientEpoch :: non_neg_integer()}
               | {describe, EntityId :: binary(), bil:description()}
               | {signal, EntityId :: binary(), bil:signal()}
               | {leave, EntityId :: binary(), left | down}
               | {detach, EntityId :: binary()}
               | {client_ack, EntityId :: binary(), Seq :: non_neg_integer()}
               | {report_binding, EntityId :: binary()}
               | {takeover, Epoch :: pos_integer()}
               | {reelected, Epoch :: pos_integer()}
               | {timeout, timer_key()}.
-type effect() :: {reply, term()}
                | {deliver, EntityId :: binary(), bil:signal()}
                | {report, EntityId :: binary(), evatar:binding_report()}
                | {drop, EntityId :: binary(), evatar:drop_code(), Reason :: binary()}
                | {accepted, EntityId :: binary(), SignalId :: binary()}
                | {start_timer, timer_key(), Ms :: non_neg_integer()}
                | {cancel_timer, timer_key()}
                | {log, logger:level(), logger:report()}.
-type phase() :: waiting | bound.
%% {@link traffic/1}: signals in and out per joined entity, open requests.
-type traffic() :: #{pending := non_neg_integer(),
                     entities := #{binary() => #{received := non_neg_integer(),
                                                 delivered := non_neg_integer()}}}.

-define(DEFAULTS, #{join_timeout => 5000, feedback_timeout => 5000, max_avatars => 64,
                   resume_timeout => 10000, dedup_window => 1024, max_unacked_out => 8192,
                   max_id_length => 128, max_open_requests => 1024, max_consumes => 256,
                   max_binding_report => 1048576}).

%% The one table of the numeric options' ranges, inclusive (docs/api.md
%% and docs/protocol.md section 7 list them): every path that makes a
%% pairing (evatar:create_pairing/2, ensure_pairing/2, the node
%% configuration file, the HTTP API) goes through config/1. A timer must
%% stay within erlang:start_timer/3's limit (2^32-1 ms, 49.7 days); counts
%% are bounded so one option cannot make a pairing hold unbounded memory.
-define(MAX_TIMER_MS, 4294967295).
-define(RANGES, #{join_timeout => {0, ?MAX_TIMER_MS},
                  feedback_timeout => {0, ?MAX_TIMER_MS},
                  resume_timeout => {0, ?MAX_TIMER_MS},
                  max_avatars => {1, 65536},
                  dedup_window => {1, 1048576},
                  max_unacked_out => {1, 1048576},
                  max_open_requests => {1, 1048576},
                  max_consumes => {1, 65536},
                  max_id_length => {1, 65536},
                  max_binding_report => {4096, 268435456}}).

%% The bytes of a Binding report that do not depend on its values: the
%% document around the Entities list, one EntityID entry, and one Bound row
%% with its Score and Candidates at 20 digits (an Unbound row is shorter).
%% evatar_pairing_logic_tests checks them against bil_control's encoder.
-define(REPORT_TAGS, 77).
-define(ENTITY_TAGS, 21).
-define(ROW_TAGS, 301).

%% ---------------------------------------------------------------------------
%% Construction
%% ---------------------------------------------------------------------------

%% @doc Checks pairing options (see `evatar:pairing_opts()') and fills in
%% the defaults.
-spec config(term()) -> {ok, config()} | {error, {bad_option, term()}}.
%% Plain credentials are hashed here; a configuration made by this
%% function is accepted again as it is.
config(Opts) when is_map(Opts) ->
    case evatar_auth:normalise(Opts) of
        {ok, Opts1} -> check_options(maps:to_list(maps:merge(?DEFAULTS, Opts1)), Opts1);
        {error, _} = Error -> Error
    end;
config(Other) ->
    {error, {bad_option, Other}}.

check_options([{K, V} | Rest], Opts) when is_map_key(K, ?RANGES) ->
    {Min, Max} = maps:get(K, ?RANGES),
    case is_integer(V) andalso V >= Min andalso V =< Max of
        true -> check_options(Rest, Opts);
        false -> {error, {bad_option, {K, V}}}
    end;
check_options([{K, V} | Rest], Opts)
  when K =:= standby_node, is_atom(V);
       K =:= agent_credential; K =:= avatar_credential; K =:= identities;
       K =:= unlisted_ids ->
    check_options(Rest, Opts);
check_options([Bad | _], _Opts) ->
    {error, {bad_option, Bad}};
check_options([], Opts) ->
    {ok, maps:merge(?DEFAULTS, Opts)}.

%% @doc Pure: the inclusive range of every numeric pairing option, as
%% config/1 checks it.
-spec option_ranges() -> #{atom() => {non_neg_integer(), pos_integer()}}.
option_ranges() ->
    ?RANGES.

%% @doc A pairing with nobody joined yet, at epoch 1.
-spec new(evatar:pairing_id(), config()) -> state().
new(PairingId, Config) ->
    #st{id = PairingId, config = Config}.

%% ---------------------------------------------------------------------------
%% Events
%% ---------------------------------------------------------------------------

%% @doc Applies one event at time `Now' (milliseconds since the epoch).
%% Call-like events (join, describe, leave) produce exactly one
%% `{reply, Reply}' effect.
-spec handle(event(), integer(), state()) -> {state(), [effect()]}.
handle(Event, Now, St) ->
    case handle1(Event, Now, St) of
        {#st{overflow = []}, _} = Result ->
            Result;
        {#st{overflow = Ids} = St1, Effects} ->
            drop_overflow(lists:usort(Ids), Now, St1#st{overflow = []}, [Effects])
    end.

handle1({signal, EntityId, Signal}, Now, St) ->
    route(EntityId, Signal, Now, received(EntityId, St));
handle1({join, Role, EntityId, Credential}, Now, St) ->
    join(Role, EntityId, Credential, undefined, Now, St);
handle1({join, Role, EntityId, Credential, SessionId}, Now, St) when is_binary(SessionId) ->
    join(Role, EntityId, Credential, SessionId, Now, St);
handle1({resume, Role, EntityId, Credential, SessionId, Received, ClientEpoch}, Now, St) ->
    resume(Role, EntityId, Credential, SessionId, Received, ClientEpoch, Now, St);
handle1({describe, EntityId, Description}, Now, St) ->
    describe(EntityId, Description, Now, St);
handle1({leave, EntityId, Why}, Now, St) ->
    {St1, Effects} = leave(EntityId, Why, Now, St),
    {St1, [{reply, ok} | Effects]};
handle1({detach, EntityId}, Now, St) ->
    detach(EntityId, Now, St);
handle1({client_ack, EntityId, Seq}, _Now, St) ->
    {client_ack(EntityId, Seq, St), []};
handle1({report_binding, EntityId}, _Now, St) ->
    {St, report_to(EntityId, St)};
handle1({takeover, Epoch}, Now, St) ->
    takeover(Epoch, Now, St);
handle1({reelected, Epoch}, _Now, #st{epoch = Old} = St) when Epoch > Old ->
    %% The active itself won a new epoch while serving (docs/ha-design.md
    %% section 5): its clients' connections are its own, so nobody is
    %% detached; only the epoch stamped from now on moves.
    {St#st{epoch = Epoch}, [{log, notice, #{what => reelected, epoch => Epoch}}]};
handle1({timeout, {join, EntityId}}, Now, St) ->
    join_timeout(EntityId, Now, St);
handle1({timeout, {resume, EntityId}}, Now, St) ->
    resume_timeout(EntityId, Now, St);
handle1({timeout, {feedback, Component, SignalId}}, Now, St) ->
    feedback_timeout({Component, SignalId}, Now, St).

%% --- join ------------------------------------------------------------------

%% A detached entity (its connection gone, kept for a Resume) is replaced by
%% a fresh join of the same id: the client came back without resuming.
join(Role, EntityId, Credential, Session, Now, #st{entities = Entities} = St) ->
    case Entities of
        #{EntityId := #entity{attached = false}} ->
            case credential_ok(Role, EntityId, Credential, St#st.config) of
                true ->
                    {St1, LeaveEffects} = leave(EntityId, replaced, Now, St),
                    {St2, JoinEffects} = join1(Role, EntityId, Credential, Session, Now, St1),
                    {St2, LeaveEffects ++ JoinEffects};
                false ->
                    join1(Role, EntityId, Credential, Session, Now, St)
            end;
        #{} ->
            join1(Role, EntityId, Credential, Session, Now, St)
    end.

join1(Role, EntityId, Credential, Session, Now,
     #st{config = Config, entities = Entities} = St) ->
    Check = case evatar_auth:check_id(EntityId, maps:get(max_id_length, Config)) of
                {error, _} = IdError -> IdError;
                ok -> join_check(Role, EntityId, Credential, St)
            end,
    case Check of
        {error, _} = Error ->
            %% Logged once, by the bridge connection that asked, which
            %% knows the client's address (agent_bridge_conn).
            {St, [{reply, Error}]};
        ok ->
            Timeout = maps:get(join_timeout, Config),
            Entity = #entity{id = EntityId, role = Role, joined_at = Now,
                             join_deadline = Now + Timeout, session = Session},
            St1 = St#st{entities = Entities#{EntityId => Entity}},
            St2 = case Role of
                      agent -> St1#st{agent = EntityId};
                      avatar -> St1#st{avatars = St1#st.avatars + 1}
                  end,
            {St2, [{reply, ok},
                   {start_timer, {join, EntityId}, Timeout},
                   {log, info, #{what => entity_joined, entity => EntityId,
                                 role => Role}}]}
    end.

join_check(Role, EntityId, Credential, #st{config = Config, entities = Entities} = St) ->
    case credential_ok(Role, EntityId, Credential, Config) of
        false -> {error, bad_credential};
        true when is_map_key(EntityId, Entities) -> {error, entity_exists};
        true when Role =:= agent, St#st.agent =/= undefined -> {error, occupied};
        true when Role =:= avatar ->
            case St#st.avatars < maps:get(max_avatars, Config) of
                true -> ok;
                false -> {error, too_many_entities}
            end;
        true -> ok
    end.

credential_ok(_Role, _EntityId, authenticated, _Config) ->
    true;
credential_ok(Role, EntityId, Given, Config) when is_binary(Given); is_map(Given) ->
    evatar_auth:verify(evatar_auth:requirement(Role, EntityId, Config), Given)
        =:= authenticated;
credential_ok(_Role, _EntityId, _Given, _Config) ->
    false.

join_timeout(EntityId, Now, #st{entities = Entities, config = Config} = St) ->
    case Entities of
        #{EntityId := #entity{description = undefined}} ->
            Ms = maps:get(join_timeout, Config),
            Message = iolist_to_binary(
                        io_lib:format("no description within the join timeout (~b ms)", [Ms])),
            {Error, St1} = mediator_signal(error, EntityId, undefined, <<"ERROR">>,
                                           <<"JoinTimeout">>, Message, Now, St),
            {St2, Deliver} = stamp(EntityId, Error, Now, St1),
            {St3, _} = remove_entity(EntityId, Now, St2),
            {count(dropped, St3),
             [Deliver, {drop, EntityId, join_timeout, Message},
              {log, warning, #{what => join_timeout, entity => EntityId}}]};
        _ ->
            {St, []}
    end.

%% --- describe --------------------------------------------------------------

describe(EntityId, Description, Now, #st{entities = Entities} = St) ->
    case Entities of
        #{EntityId := Entity} ->
            case check_description(Entity, Description, St) of
                {ok, Charge} ->
                    register(Entity, Description, Charge, Now, St);
                {error, Message} ->
                    {St, [{reply, {error, Message}},
                          {log, notice, #{what => description_refused,
                                          entity => EntityId, reason => Message}}]}
            end;
        #{} ->
            {St, [{reply, {error, <<"this entity has not joined the pairing">>}}]}
    end.

check_description(#entity{id = Id, role = Role},
                  #{entity_id := DescId, entity_type := Type,
                    components := Components} = Description, St) ->
    case well_formed(Description) of
        false ->
            {error, <<"malformed description">>};
        true when DescId =/= Id ->
            {error, <<"EntityID '", DescId/binary, "' differs from the joined entity id '",
                      Id/binary, "'">>};
        true when Type =/= Role ->
            {error, <<"EntityType ", (type_name(Type))/binary,
                      " does not match the role ", (type_name(Role))/binary>>};
        true ->
            case check_components([C || #{id := C} <- Components], Id, #{}, St) of
                ok -> check_report(Id, Components, St);
                {error, _} = Error -> Error
            end
    end;
check_description(_Entity, _Description, _St) ->
    {error, <<"malformed description">>}.

check_components([C | Rest], Id, Seen, #st{components = Owners, config = Config} = St) ->
    Max = maps:get(max_id_length, Config),
    case evatar_auth:check_id(C, Max) of
        {error, id_too_long} ->
            {error, <<"ComponentID '", (evatar_auth:log_id(C))/binary, "' is longer than ",
                      (integer_to_binary(Max))/binary, " bytes (max_id_length)">>};
        {error, reserved_id} ->
            {error, <<"ComponentID '", C/binary, "' is reserved: it reads as EVATAR">>};
        ok ->
            check_component(C, Rest, Id, Seen, Owners, St)
    end;
check_components([], _Id, _Seen, _St) ->
    ok.

check_component(C, Rest, Id, Seen, Owners, St) ->
    case Owners of
        _ when is_map_key(C, Seen) ->
            {error, <<"ComponentID '", C/binary, "' appears twice">>};
        #{C := Owner} when Owner =/= Id ->
            {error, <<"ComponentID '", C/binary, "' is already used by entity '",
                      Owner/binary, "'">>};
        #{} ->
            check_components(Rest, Id, Seen#{C => true}, St)
    end.

%% Every value a Binding report repeats is at most max_id_length bytes as
%% the report writes it, a description has at most max_consumes Consumes
%% entries (one report row each), and the report stays within
%% max_binding_report bytes however the pairing binds: each row is counted
%% as a Bound row whose provider ids have the longest length allowed.
%% Returns the bytes this entity adds to a report at most.
check_report(Id, Components, #st{config = Config, charges = Charges, charged = Charged}) ->
    Max = maps:get(max_id_length, Config),
    Entries = [{C, E} || #{id := C, services := S, consumes := U} <- Components,
                         E <- S ++ U],
    Long = [{C, Field} || {C, #{category := Cat, type := Type}} <- Entries,
                          {Field, V} <- [{<<"ServiceCategory">>, Cat},
                                         {<<"ServiceType">>, Type}],
                          evatar_auth:escaped_size(V) > Max],
    Consumes = [{C, E} || #{id := C, consumes := U} <- Components, E <- U],
    IdSize = evatar_auth:escaped_size(Id),
    Charge = ?ENTITY_TAGS + IdSize +
        lists:sum([?ROW_TAGS + IdSize + evatar_auth:escaped_size(C) +
                   evatar_auth:escaped_size(Cat) + evatar_auth:escaped_size(Type) + 2 * Max
                   || {C, #{category := Cat, type := Type}} <- Consumes]),
    Total = ?REPORT_TAGS + Charged - maps:get(Id, Charges, 0) + Charge,
    Report = maps:get(max_binding_report, Config),
    MaxConsumes = maps:get(max_consumes, Config),
    case {Long, length(Consumes)} of
        {[{C, Field} | _], _} ->
            {error, <<Field/binary, " of ComponentID '", C/binary, "' is longer than ",
                      (integer_to_binary(Max))/binary, " bytes (max_id_length)">>};
        {[], N} when N > MaxConsumes ->
            {error, <<(integer_to_binary(N))/binary, " Consumes entries, over the pairing's ",
                      (integer_to_binary(MaxConsumes))/binary, " (max_consumes)">>};
        {[], _} when Total > Report ->
            {error, <<"with this description the pairing's Binding report could reach ",
                      (integer_to_binary(Total))/binary, " bytes, over its ",
                      (integer_to_binary(Report))/binary, " (max_binding_report)">>};
        {[], _} ->
            {ok, Charge}
    end.

%% The bridge hands over parser output; this guards the Erlang API against
%% terms that would make the binding code raise.
well_formed(#{entity_id := E, entity_type := T, components := Cs})
  when is_binary(E), (T =:= agent orelse T =:= avatar), is_list(Cs) ->
    lists:all(fun(#{id := C, services := S, consumes := U})
                    when is_binary(C), is_list(S), is_list(U) ->
                      lists:all(fun well_formed_entry/1, S ++ U);
                 (_) ->
                      false
              end, Cs);
well_formed(_) ->
    false.

well_formed_entry(#{category := C, type := T, parameters := Ps})
  when is_binary(C), is_binary(T), is_list(Ps) ->
    lists:all(fun({N, V}) -> is_binary(N) andalso is_binary(V);
                 (_) -> false
              end, Ps);
well_formed_entry(_) ->
    false.

type_name(agent) -> <<"Agent">>;
type_name(avatar) -> <<"Avatar">>;
type_name(Other) when is_binary(Other) -> Other;
type_name(_) -> <<"(invalid)">>.

register(#entity{id = Id, description = Old} = Entity, Description, Charge, Now,
         #st{charges = Charges, charged = Charged} = St0) ->
    St = St0#st{charges = Charges#{Id => Charge},
                charged = Charged - maps:get(Id, Charges, 0) + Charge},
    Components0 = maps:without(component_ids(Old), St#st.components),
    Components = lists:foldl(fun(C, Acc) -> Acc#{C => Id} end, Components0,
                             component_ids(Description)),
    {Order, JoinEffects} = case Old of
                               undefined -> {St#st.order ++ [Id],
                                             [{cancel_timer, {join, Id}}]};
                               _ -> {St#st.order, []}
                           end,
    St1 = St#st{entities = (St#st.entities)#{Id => Entity#entity{description = Description}},
                components = Components, order = Order},
    {St2, Effects} = rebind(Now, St1),
    {St2, [{reply, ok} | JoinEffects] ++
         [{log, info, #{what => registered, entity => Id,
                        components => length(component_ids(Description))}} | Effects]}.

component_ids(undefined) -> [];
component_ids(#{components := Components}) -> [C || #{id := C} <- Components].

%% --- binding ---------------------------------------------------------------

%% Recomputes the Body Mapping Registry after any registration change, closes
%% requests whose provider is no longer bound to their requester, and reports
%% the result to every registered entity.
rebind(Now, #st{order = Order, entities = Entities} = St) ->
    Descriptions = [D || Id <- Order, #entity{description = D} <- [maps:get(Id, Entities)]],
    #{bound := Bound, unbound := Unbound} = bil:bind(Descriptions),
    St1 = count(rebinds, St#st{bound = Bound, unbound = Unbound, routes = routes(Bound)}),
    {St2, GoneEffects} = close_unbound_requests(Now, St1),
    Report = #{bound => Bound, unbound => Unbound, entities => Order},
    {St2, GoneEffects ++ [{report, Id, Report} || Id <- Order] ++
         [{log, info, #{what => bound, bound => length(Bound),
                        unbound => length(Unbound), entities => Order}}]}.

routes(Bound) ->
    Reverse = maps:from_list([{{P, C}, reverse} || #{consumer := #{component := C},
                                                      provider := #{component := P}} <- Bound]),
    lists:foldl(fun(#{consumer := #{component := C}, provider := #{component := P}}, Acc) ->
                        Acc#{{C, P} => forward}
                end, Reverse, Bound).

%% Voids, in key order, every open request whose provider is no longer
%% bound to its requester. Effects are gathered in reverse and turned once:
%% appending per request made voiding 15,000 requests take seconds.
close_unbound_requests(Now, #st{pending = Pending, routes = Routes} = St) ->
    Gone = [{Key, P} || {{Req, _} = Key, #pending{provider = Prov} = P}
                            <- lists:sort(maps:to_list(Pending)),
                        not is_map_key({Req, Prov}, Routes)],
    {St1, RevEffects} =
        lists:foldl(fun({{Req, SigId} = Key, #pending{requester = Entity, provider = Prov} = P},
                        {StAcc, Acc}) ->
                            StAcc1 = drop_pending(Key, StAcc),
                            {Sig, StAcc2} = mediator_signal(
                                              feedback, Req, SigId, <<"EVATAR">>,
                                              <<"ProviderGone">>,
                                              <<"the provider component '", Prov/binary,
                                                "' is no longer bound; the request is void">>,
                                              Now, StAcc1),
                            {StAcc3, Deliver} = stamp(Entity, Sig, Now, StAcc2),
                            {StAcc4, Closed} = request_closed(
                                                 P, SigId, <<"Unbound">>,
                                                 <<"your component is no longer bound to the "
                                                   "requester; the request is void">>,
                                                 Now, StAcc3),
                            {count(provider_gone, StAcc4),
                             lists:reverse(Closed) ++
                                 [{log, notice, #{what => provider_gone, entity => Entity,
                                                  signal => SigId, provider => Prov}},
                                  Deliver, {cancel_timer, {feedback, Req, SigId}} | Acc]}
                    end, {St, []}, Gone),
    {St1, lists:reverse(RevEffects)}.

%% --- leave -----------------------------------------------------------------

leave(EntityId, Why, Now, #st{entities = Entities} = St) when is_atom(Why) ->
    case Entities of
        #{EntityId := #entity{description = Description}} ->
            {St1, Effects} = remove_entity(EntityId, Now, St),
            Log = {log, info, #{what => entity_left, entity => EntityId, why => Why}},
            case Description of
                undefined ->
                    {St1, [Log | Effects]};
                _ ->
                    {St2, RebindEffects} = rebind(Now, St1),
                    {St2, [Log | Effects] ++ RebindEffects}
            end;
        #{} ->
            {St, []}
    end.

%% Forgets the entity, its components and the requests it was waiting on
%% (their providers are told RequestClosed); the caller rebinds when the
%% entity had registered.
remove_entity(EntityId, Now, #st{entities = Entities} = St) ->
    #entity{role = Role, description = Description} = maps:get(EntityId, Entities),
    St1 = case Role of
              agent -> St#st{agent = undefined};
              avatar -> St#st{avatars = St#st.avatars - 1}
          end,
    {Mine, Others} = maps:fold(fun(K, #pending{requester = R} = P, {M, O}) when R =:= EntityId ->
                                       {[{K, P} | M], O};
                                  (K, P, {M, O}) ->
                                       {M, O#{K => P}}
                               end, {[], #{}}, St#st.pending),
    St2 = St1#st{entities = maps:remove(EntityId, Entities),
                 order = lists:delete(EntityId, St#st.order),
                 components = maps:without(component_ids(Description), St#st.components),
                 pending = Others,
                 open = maps:remove(EntityId, St#st.open),
                 charges = maps:remove(EntityId, St#st.charges),
                 charged = St#st.charged - maps:get(EntityId, St#st.charges, 0),
                 counters = maps:remove({received, EntityId}, St1#st.counters)},
    JoinTimer = case Description of
                    undefined -> [{cancel_timer, {join, EntityId}}];
                    _ -> []
                end,
    ResumeTimer = case maps:get(EntityId, Entities) of
                      #entity{resume_deadline = undefined} -> [];
                      _ -> [{cancel_timer, {resume, EntityId}}]
                  end,
    {St3, Closed} = lists:foldl(
                      fun({{_, S}, P}, {StAcc, Acc}) ->
                              {StAcc1, Deliver} = request_closed(
                                                    P, S, <<"RequesterGone">>,
                                                    <<"the requester left the pairing">>,
                                                    Now, StAcc),
                              {StAcc1, [Deliver | Acc]}
                      end, {St2, []}, lists:sort(Mine)),
    {St3, JoinTimer ++ ResumeTimer ++
         [{cancel_timer, {feedback, C, S}} || {{C, S}, _} <- lists:sort(Mine)] ++
         lists:append(lists:reverse(Closed))}.

%% --- routing ---------------------------------------------------------------

route(EntityId, #{id := Id, context := Context, sender := Sender, receiver := Receiver,
                  body := Body} = Signal, Now, #st{entities = Entities} = St)
  when is_binary(Id), is_atom(Context), is_binary(Sender), is_binary(Receiver),
       is_map(Body) ->
    case Entities of
        #{EntityId := #entity{session = undefined, description = undefined}} ->
            refuse(EntityId, Signal, <<"NotDescribed">>,
                   <<"send your description before any signal">>, Now, St);
        #{EntityId := #entity{session = undefined}} ->
            route_known(EntityId, Signal, Now, St);
        #{EntityId := #entity{seen = Seen}} when is_map_key(Id, Seen) ->
            %% Resent after a reconnect: accepted before, so not again.
            {count(duplicates, St), [{accepted, EntityId, Id}]};
        #{EntityId := #entity{description = Description} = Entity} ->
            St1 = St#st{entities = Entities#{EntityId := remember(Id, Entity, St)}},
            {St2, Effects} = case Description of
                                 undefined ->
                                     refuse(EntityId, Signal, <<"NotDescribed">>,
                                            <<"send your description before any signal">>,
                                            Now, St1);
                                 _ ->
                                     route_known(EntityId, Signal, Now, St1)
                             end,
            {St2, Effects ++ [{accepted, EntityId, Id}]};
        #{} ->
            %% Left or dropped while the signal was in flight: nobody to tell.
            {count(unknown_entity, St), []}
    end;
route(EntityId, Signal, Now, St) ->
    case is_map_key(EntityId, St#st.entities) of
        true ->
            Fake = #{id => field(id, Signal), sender => field(sender, Signal)},
            refuse(EntityId, Fake, <<"BadSignal">>, <<"malformed signal">>, Now, St);
        false ->
            {count(unknown_entity, St), []}
    end.

field(Key, Signal) when is_map(Signal) ->
    case maps:get(Key, Signal, undefined) of
        V when is_binary(V) -> V;
        _ -> <<>>
    end;
field(_Key, _Signal) ->
    <<>>.

route_known(EntityId, #{origin := _} = Signal, Now, St) ->
    refuse(EntityId, Signal, <<"BadSignal">>,
           <<"Origin is EVATAR's mark on its own signals; an entity does not send it">>,
           Now, St);
route_known(EntityId, #{id := Id} = Signal, Now, #st{config = Config} = St)
  when byte_size(Id) > 0 ->
    Max = maps:get(max_id_length, Config),
    case evatar_auth:escaped_size(Id) > Max orelse
        evatar_auth:escaped_size(field(in_reply_to, Signal)) > Max of
        true ->
            refuse(EntityId, Signal#{id := <<>>}, <<"IdTooLong">>,
                   <<"SignalID and InReplyTo are at most ", (integer_to_binary(Max))/binary,
                     " bytes (max_id_length)">>, Now, St);
        false ->
            route_checked(EntityId, Signal, Now, St)
    end;
route_known(EntityId, Signal, Now, St) ->
    route_checked(EntityId, Signal, Now, St).

route_checked(EntityId, #{sender := Sender, receiver := Receiver} = Signal, Now,
              #st{components = Components, routes = Routes} = St) ->
    case Components of
        #{Sender := EntityId} ->
            case Components of
                #{Receiver := Target} when is_map_key({Sender, Receiver}, Routes) ->
                    route_bound(Target, Signal, Now, St);
                #{Receiver := _} ->
                    refuse(EntityId, Signal, <<"NotBound">>,
                           <<"'", Receiver/binary, "' is not bound to '", Sender/binary, "'">>,
                           Now, St);
                #{} ->
                    refuse(EntityId, Signal, <<"UnknownReceiver">>,
                           <<"no component '", Receiver/binary, "' in this pairing">>, Now, St)
            end;
        #{} ->
            refuse(EntityId, Signal, <<"BadSender">>,
                   <<"'", Sender/binary, "' is not a component of your description">>, Now, St)
    end.

route_bound(Target, #{context := request, id := Id, sender := Sender} = Signal, Now, St) ->
    Key = {Sender, Id},
    case is_map_key(Key, St#st.pending) of
        true ->
            refuse(maps:get(Sender, St#st.components), Signal, <<"DuplicateRequest">>,
                   <<"a request with this SignalID is still open">>, Now, St);
        false ->
            Requester = maps:get(Sender, St#st.components),
            Max = maps:get(max_open_requests, St#st.config),
            case maps:get(Requester, St#st.open, 0) of
                Open when Open >= Max ->
                    refuse(Requester, Signal, <<"TooManyRequests">>,
                           <<"you have ", (integer_to_binary(Open))/binary,
                             " requests open, the pairing's max_open_requests: wait for"
                             " their Feedback">>, Now, St);
                Open ->
                    open_request(Requester, Open, Target, Signal, Now, St)
            end
    end;
route_bound(Target, #{context := Context} = Signal, Now, St)
  when Context =:= feedback; Context =:= progress; Context =:= error ->
    answer(Target, Signal, Now, St);
route_bound(Target, #{context := Context} = Signal, Now, St)
  when Context =:= sensor_data; Context =:= request_no_feedback; Context =:= event ->
    {St1, Deliver} = stamp(Target, Signal, Now, St),
    {count({routed, Context}, St1), [Deliver]};
route_bound(_Target, #{sender := Sender} = Signal, Now, St) ->
    refuse(maps:get(Sender, St#st.components), Signal, <<"BadSignal">>,
           <<"unknown signal context">>, Now, St).

open_request(Requester, Open, Target, #{id := Id, sender := Sender, receiver := Receiver} = Signal,
             Now, St) ->
    Key = {Sender, Id},
    Timeout = maps:get(feedback_timeout, St#st.config),
    P = #pending{requester = Requester, provider = Receiver,
                 provider_entity = Target, deadline = Now + Timeout},
    St1 = St#st{pending = (St#st.pending)#{Key => P},
                open = (St#st.open)#{Requester => Open + 1}},
    {St2, Deliver} = stamp(Target, Signal, Now, St1),
    {count({routed, request}, St2),
     [Deliver, {start_timer, {feedback, Sender, Id}, Timeout}]}.

%% Forgets an open request and counts it off its requester's.
drop_pending(Key, #st{pending = Pending, open = Open} = St) ->
    case Pending of
        #{Key := #pending{requester = R}} ->
            Open1 = case maps:get(R, Open, 0) of
                        N when N > 1 -> Open#{R => N - 1};
                        _ -> maps:remove(R, Open)
                    end,
            St#st{pending = maps:remove(Key, Pending), open = Open1};
        #{} ->
            St
    end.

%% Feedback closes the open request it answers, progress keeps it open and
%% moves its deadline to a full feedback timeout from now, an error answering
%% a request closes it like feedback. A Feedback or Progress matching no open
%% request (late, or never asked) is not delivered: its sender gets the error
%% NoOpenRequest, and it is counted; an error signal that answers nothing is
%% delivered as ordinary traffic (docs/protocol.md section 4.3).
answer(Target, #{context := Context, sender := Sender, receiver := Receiver} = Signal,
       Now, #st{pending = Pending} = St) ->
    InReplyTo = maps:get(in_reply_to, Signal, undefined),
    Key = {Receiver, InReplyTo},
    case Pending of
        #{Key := #pending{provider = Sender} = P} when Context =:= progress ->
            Timeout = maps:get(feedback_timeout, St#st.config),
            St1 = St#st{pending = Pending#{Key => P#pending{deadline = Now + Timeout}}},
            {St2, Deliver} = stamp(Target, Signal, Now, St1),
            {count({routed, progress}, St2),
             [Deliver, {start_timer, {feedback, Receiver, InReplyTo}, Timeout}]};
        #{Key := #pending{provider = Sender}} ->
            St1 = drop_pending(Key, St),
            {St2, Deliver} = stamp(Target, Signal, Now, St1),
            {count({routed, Context}, St2),
             [{cancel_timer, {feedback, Receiver, InReplyTo}}, Deliver]};
        #{} when Context =:= error ->
            {St1, Deliver} = stamp(Target, Signal, Now, St),
            {count({routed, error}, St1), [Deliver]};
        #{} ->
            %% Late (the request timed out or was voided), answered twice,
            %% or never asked: the sender learns it was not delivered.
            SenderEntity = maps:get(Sender, St#st.components),
            {St1, Effects} = refuse(SenderEntity, Signal, <<"NoOpenRequest">>,
                                    <<"no open request '", (in_reply_to_text(InReplyTo))/binary,
                                      "' of '", Receiver/binary, "' awaits your answer (it was "
                                      "answered, timed out or voided); not delivered">>,
                                    Now, St),
            {count(late_feedback, St1),
             Effects ++ [{log, notice, #{what => late_feedback, entity => SenderEntity,
                                         signal => maps:get(id, Signal),
                                         in_reply_to => InReplyTo}}]}
    end.

in_reply_to_text(undefined) -> <<"(no InReplyTo)">>;
in_reply_to_text(Id) -> Id.

feedback_timeout({Requester, SignalId} = Key, Now, #st{pending = Pending} = St) ->
    case Pending of
        #{Key := #pending{requester = Entity, provider = Provider} = P} ->
            St1 = drop_pending(Key, St),
            Message = <<"no feedback from '", Provider/binary, "' within the feedback timeout">>,
            {Sig, St2} = mediator_signal(feedback, Requester, SignalId, ?MEDIATOR,
                                         <<"Timeout">>, Message, Now, St1),
            {St3, Deliver} = stamp(Entity, Sig, Now, St2),
            {St4, Closed} = request_closed(P, SignalId, <<"Timeout">>,
                                           <<"the requester's feedback timeout passed; "
                                             "an answer now is refused (NoOpenRequest)">>,
                                           Now, St3),
            {count(timeouts, St4),
             [Deliver | Closed] ++
                 [{log, warning, #{what => feedback_timeout, entity => Entity,
                                   signal => SignalId, provider => Provider}}]};
        #{} ->
            {St, []}
    end.

%% An error signal back to the sending entity, and nothing else.
refuse(EntityId, Signal, Code, Message, Now, St) ->
    Receiver = case maps:get(sender, Signal, <<>>) of
                   <<>> -> EntityId;
                   S -> S
               end,
    InReplyTo = case maps:get(id, Signal, <<>>) of
                    <<>> -> undefined;
                    I -> I
                end,
    {Sig, St1} = mediator_signal(error, Receiver, InReplyTo, <<"ERROR">>, Code, Message, Now, St),
    {St2, Deliver} = stamp(EntityId, Sig, Now, St1),
    {count({error, Code}, St2),
     [Deliver, {log, notice, #{what => signal_refused, entity => EntityId, code => Code,
                               signal => InReplyTo}}]}.

mediator_signal(Context, Receiver, InReplyTo, Category, Type, Message, Now, St) ->
    mediator_signal(Context, Receiver, InReplyTo, Category, Type,
                    [{<<"Message">>, Message}], Now, St, params).

mediator_signal(Context, Receiver, InReplyTo, Category, Type, Params, Now,
                #st{next_id = N} = St, params) ->
    Sig = #{id => <<"evatar-", (integer_to_binary(N))/binary>>,
            context => Context,
            sender => ?MEDIATOR,
            origin => evatar,
            receiver => Receiver,
            in_reply_to => InReplyTo,
            timestamp => max(Now, 0),
            seq => undefined,
            epoch => undefined,
            body => #{category => Category, type => Type, parameters => Params}},
    {Sig, St#st{next_id = N + 1}}.

%% EVATAR closed an open request without its provider's answer: the
%% provider, when it is still registered, is told by an Event RequestClosed
%% (docs/protocol.md section 4.3), so it can stop the work; an answer it
%% sends later is refused NoOpenRequest.
request_closed(#pending{provider = Prov, provider_entity = PE}, SignalId, Reason, Message,
               Now, #st{entities = Entities} = St) ->
    case Entities of
        #{PE := _} ->
            {Sig, St1} = mediator_signal(event, Prov, SignalId, ?MEDIATOR,
                                         <<"RequestClosed">>,
                                         [{<<"Reason">>, Reason}, {<<"Message">>, Message}],
                                         Now, St, params),
            {St2, Deliver} = stamp(PE, Sig, Now, St1),
            {St2, [Deliver]};
        #{} ->
            {St, []}
    end.

%% The current Binding report, to one joined entity (a GetBinding, a
%% resumed session), described or not.
report_to(EntityId, #st{entities = Entities} = St) ->
    case Entities of
        #{EntityId := #entity{}} ->
            [{report, EntityId, bindings(St)}];
        #{} ->
            []
    end.

%% Stamps the receiving entity's next sequence number and the epoch; an HA
%% entity also keeps the signal until it acknowledges it.
stamp(EntityId, Signal, Now, #st{entities = Entities, epoch = Epoch} = St) ->
    #entity{seq = Seq} = Entity = maps:get(EntityId, Entities),
    Next = Seq + 1,
    Stamped = Signal#{seq => Next, epoch => Epoch},
    case Entity of
        #entity{session = undefined} ->
            {St#st{entities = Entities#{EntityId := Entity#entity{seq = Next}}},
             {deliver, EntityId, Stamped}};
        #entity{out = Out, outn = N} ->
            Max = maps:get(max_unacked_out, St#st.config),
            Entity1 = Entity#entity{seq = Next, out = queue:in({Next, Stamped, Now}, Out),
                                    outn = N + 1},
            St1 = St#st{entities = Entities#{EntityId := Entity1}},
            St2 = case N + 1 > Max of
                      true -> St1#st{overflow = [EntityId | St1#st.overflow]};
                      false -> St1
                  end,
            {St2, {deliver, EntityId, Stamped}}
    end.

%% Adds a SignalID to the entity's de-duplication window, forgetting the
%% oldest beyond dedup_window.
remember(Id, #entity{seen = Seen, seen_q = Q} = Entity, #st{config = Config}) ->
    Q1 = queue:in(Id, Q),
    Entity1 = Entity#entity{seen = Seen#{Id => true}, seen_q = Q1, last_accepted = Id},
    case map_size(Seen) + 1 > maps:get(dedup_window, Config) of
        true ->
            {{value, Old}, Q2} = queue:out(Q1),
            Entity1#entity{seen = maps:remove(Old, Entity1#entity.seen), seen_q = Q2};
        false ->
            Entity1
    end.

%% --- high availability: sessions ------------------------------------------

%% Resumes the session `SessionId' of `EntityId': the entity is attached
%% again and everything delivered after `Received' is delivered again (with
%% the current epoch). An unknown session, or one that never described
%% itself, is a fresh join; the reply says which: `{ok, Resumed,
%% LastAccepted}'. A known session presented with a
%% newer epoch than this instance's is refused (`stale_epoch'): this
%% instance is behind one the client has already talked to.
resume(Role, EntityId, Credential, SessionId, Received, ClientEpoch, Now,
       #st{entities = Entities, epoch = Epoch} = St) ->
    case credential_ok(Role, EntityId, Credential, St#st.config) of
        false ->
            {St, [{reply, {error, bad_credential}}]};
        true ->
            case Entities of
                #{EntityId := #entity{session = SessionId, role = Role}}
                  when is_binary(SessionId), ClientEpoch > Epoch ->
                    %% This instance holds the session but is older than one
                    %% the client has seen: it must not serve it.
                    {St, [{reply, {error, stale_epoch}},
                          {log, notice, #{what => resume_refused, entity => EntityId,
                                          reason => stale_epoch,
                                          client_epoch => ClientEpoch}}]};
                #{EntityId := #entity{session = SessionId, role = Role,
                                      description = undefined}}
                  when is_binary(SessionId) ->
                    %% Joined but never described (its description was lost
                    %% with the connection that carried it): `Resumed' true
                    %% would tell the client its description is held, and
                    %% its signals would all be refused NotDescribed until
                    %% the join timeout. It starts afresh, as an unknown
                    %% session does, and describes itself again.
                    {St1, LeaveEffects} = leave(EntityId, replaced, Now, St),
                    {St2, JoinEffects} = join1(Role, EntityId, Credential, SessionId, Now, St1),
                    case lists:keytake(reply, 1, JoinEffects) of
                        {value, {reply, ok}, Rest} ->
                            {St2, [{reply, {ok, false, <<>>}} | LeaveEffects ++ Rest]};
                        {value, _Refusal, _} ->
                            {St2, LeaveEffects ++ JoinEffects}
                    end;
                #{EntityId := #entity{session = SessionId, role = Role} = Entity}
                  when is_binary(SessionId) ->
                    %% A client that saw more than this history holds
                    %% (two-node partition, docs/ha-design.md section 8) must not
                    %% see those Sequence numbers again for other signals.
                    Entity1 = trim(Entity#entity{attached = true, resume_deadline = undefined,
                                                 seq = max(Entity#entity.seq, Received)},
                                   Received),
                    Redeliver = [{deliver, EntityId, Sig#{epoch => Epoch}}
                                 || {_, Sig, _} <- queue:to_list(Entity1#entity.out)],
                    St1 = St#st{entities = Entities#{EntityId := Entity1}},
                    %% The Binding report first: bindings may have changed
                    %% while the session was detached (docs/protocol.md 11.2).
                    {count(resumed, St1),
                     [{reply, {ok, true, Entity1#entity.last_accepted}},
                      {cancel_timer, {resume, EntityId}}] ++ report_to(EntityId, St1) ++
                         Redeliver ++
                         [{log, info, #{what => resumed, entity => EntityId,
                                        redelivered => length(Redeliver)}}]};
                #{} ->
                    {St1, Effects} = join(Role, EntityId, Credential, SessionId, Now, St),
                    case lists:keytake(reply, 1, Effects) of
                        {value, {reply, ok}, Rest} -> {St1, [{reply, {ok, false, <<>>}} | Rest]};
                        {value, _Refusal, _} -> {St1, Effects}
                    end
            end
    end.

%% The connection of an HA entity went: keep it for resume_timeout ms. A
%% protocol version 1 entity leaves at once, as before.
detach(EntityId, Now, #st{entities = Entities, config = Config} = St) ->
    case Entities of
        #{EntityId := #entity{session = undefined}} ->
            leave(EntityId, down, Now, St);
        #{EntityId := #entity{} = Entity} ->
            Timeout = maps:get(resume_timeout, Config),
            Entity1 = Entity#entity{attached = false, resume_deadline = Now + Timeout},
            {St#st{entities = Entities#{EntityId := Entity1}},
             [{start_timer, {resume, EntityId}, Timeout},
              {log, info, #{what => detached, entity => EntityId}}]};
        #{} ->
            {St, []}
    end.

resume_timeout(EntityId, Now, #st{entities = Entities} = St) ->
    case Entities of
        #{EntityId := #entity{attached = false}} ->
            leave(EntityId, resume_timeout, Now, St);
        #{} ->
            {St, []}
    end.

client_ack(EntityId, Seq, #st{entities = Entities} = St) when is_integer(Seq) ->
    case Entities of
        #{EntityId := #entity{session = S} = Entity} when is_binary(S) ->
            St#st{entities = Entities#{EntityId := trim(Entity, Seq)}};
        #{} ->
            St
    end;
client_ack(_EntityId, _Seq, St) ->
    St.

trim(#entity{out = Out, outn = N} = Entity, Seq) ->
    case queue:peek(Out) of
        {value, {S, _, _}} when S =< Seq ->
            trim(Entity#entity{out = queue:drop(Out), outn = N - 1}, Seq);
        _ ->
            Entity
    end.

%% This instance takes over at `Epoch': every entity's connection was to the
%% old active, so all are detached until they resume (or leave after
%% resume_timeout).
takeover(Epoch, Now, #st{entities = Entities, config = Config} = St) ->
    Timeout = maps:get(resume_timeout, Config),
    Detached = maps:map(fun(_, E) -> E#entity{attached = false,
                                              resume_deadline = Now + Timeout}
                        end, Entities),
    {St#st{epoch = Epoch, entities = Detached},
     [{start_timer, {resume, Id}, Timeout} || Id <- lists:sort(maps:keys(Entities))] ++
         [{log, notice, #{what => takeover, epoch => Epoch}}]}.

%% Entities whose unacknowledged outbound signals went over max_unacked_out
%% are dropped as slow consumers, as the bridge drops a client that does not
%% read.
drop_overflow([Id | Ids], Now, St, Effects) ->
    case St#st.entities of
        #{Id := _} ->
            {St1, LeaveEffects} = leave(Id, slow_consumer, Now, St),
            Message = <<"too many delivered signals not acknowledged">>,
            drop_overflow(Ids, Now, count(dropped, St1),
                          [[{drop, Id, slow_consumer, Message} | LeaveEffects] | Effects]);
        #{} ->
            drop_overflow(Ids, Now, St, Effects)
    end;
drop_overflow([], _Now, St, Effects) ->
    {St, lists:append(lists:reverse(Effects))}.

count(Key, #st{counters = Counters} = St) ->
    St#st{counters = maps:update_with(Key, fun(N) -> N + 1 end, 1, Counters)}.

%% Every signal a joined entity sends counts, refused or not. Kept among the
%% counters, not in the entity record, so a snapshot keeps its shape.
received(EntityId, #st{entities = Entities} = St) when is_map_key(EntityId, Entities) ->
    count({received, EntityId}, St);
received(_EntityId, St) ->
    St.

%% ---------------------------------------------------------------------------
%% Queries
%% ---------------------------------------------------------------------------

%% @doc `bound' once an agent and at least one avatar have registered.
-spec phase(state()) -> phase().
phase(#st{agent = Agent, entities = Entities, order = Order}) ->
    AgentRegistered = Agent =/= undefined andalso lists:member(Agent, Order),
    AvatarRegistered = lists:any(fun(Id) -> (maps:get(Id, Entities))#entity.role =:= avatar end,
                                 Order),
    case AgentRegistered andalso AvatarRegistered of
        true -> bound;
        false -> waiting
    end.

%% @doc The pairing's id.
-spec pairing_id(state()) -> evatar:pairing_id().
pairing_id(#st{id = Id}) -> Id.

%% @doc The pairing's epoch (stamped on every delivered signal).
-spec epoch(state()) -> pos_integer().
epoch(#st{epoch = Epoch}) -> Epoch.

%% @doc The ids of the joined entities.
-spec entity_ids(state()) -> [binary()].
entity_ids(#st{entities = Entities}) -> lists:sort(maps:keys(Entities)).

%% @doc One line of `evatar:pairings()'.
-spec summary(state()) -> map().
summary(#st{} = St) ->
    #{state => phase(St),
      agent => St#st.agent,
      avatars => St#st.avatars,
      registered => length(St#st.order),
      bound => length(St#st.bound),
      unbound => length(St#st.unbound),
      pending => map_size(St#st.pending),
      epoch => St#st.epoch}.

%% @doc The Body Mapping Registry.
-spec bindings(state()) -> evatar:binding_report().
bindings(#st{bound = Bound, unbound = Unbound, order = Order}) ->
    #{bound => Bound, unbound => Unbound, entities => Order}.

%% @doc The Service Registration List: every joined entity, registered ones
%% first in registration order, then the ones still expected to describe
%% themselves, by join time.
-spec registration_list(state()) -> [map()].
registration_list(#st{entities = Entities, order = Order}) ->
    Waiting = lists:sort([{J, Id} || #entity{id = Id, description = undefined,
                                             joined_at = J} <- maps:values(Entities)]),
    [entry(maps:get(Id, Entities)) || Id <- Order ++ [Id || {_, Id} <- Waiting]].

entry(#entity{id = Id, role = Role, joined_at = J, description = D, seq = Seq,
              session = S, attached = A, outn = N}) ->
    #{entity => Id, role => Role, joined_at => J, registered => D =/= undefined,
      description => D, delivered => Seq, session => S, attached => A, unacked => N}.

%% @doc Counters since the pairing started.
-spec stats(state()) -> map().
stats(#st{counters = C, pending = Pending}) ->
    Routed = maps:from_list([{Ctx, N} || {{routed, Ctx}, N} <- maps:to_list(C)]),
    Errors = maps:from_list([{Code, N} || {{error, Code}, N} <- maps:to_list(C)]),
    #{routed => Routed,
      errors => Errors,
      timeouts => maps:get(timeouts, C, 0),
      late_feedback => maps:get(late_feedback, C, 0),
      provider_gone => maps:get(provider_gone, C, 0),
      dropped => maps:get(dropped, C, 0),
      rebinds => maps:get(rebinds, C, 0),
      unknown_entity => maps:get(unknown_entity, C, 0),
      duplicates => maps:get(duplicates, C, 0),
      resumed => maps:get(resumed, C, 0),
      pending => map_size(Pending)}.

%% @doc Per joined entity, how many signals it has sent the pairing
%% (`received', refused ones too) and how many the pairing has delivered to
%% it (`delivered', its last Sequence), and the requests open: what a
%% simulation compares with its own counts to know that nothing is in
%% flight. Costs a pass over the entities, no description is copied.
-spec traffic(state()) -> traffic().
traffic(#st{entities = Entities, counters = C, pending = Pending}) ->
    #{pending => map_size(Pending),
      entities => maps:map(fun(Id, #entity{seq = Seq}) ->
                                   #{received => maps:get({received, Id}, C, 0), delivered => Seq}
                           end, Entities)}.

%% @doc The timers the state needs at time `Now', with their remaining time:
%% what a process taking over this state (issue 5) arms before going on.
-spec timers(state(), integer()) -> [{timer_key(), non_neg_integer()}].
timers(#st{entities = Entities, pending = Pending}, Now) ->
    [{{join, Id}, max(0, D - Now)} || #entity{id = Id, description = undefined,
                                              join_deadline = D} <- maps:values(Entities)] ++
    [{{resume, Id}, max(0, D - Now)} || #entity{id = Id, resume_deadline = D}
                                            <- maps:values(Entities), D =/= undefined] ++
    [{{feedback, C, S}, max(0, D - Now)} || {{C, S}, #pending{deadline = D}} <- maps:to_list(Pending)].

%% @doc The pairing's configuration.
-spec config_of(state()) -> config().
config_of(#st{config = Config}) -> Config.

%% @doc For every attached HA entity holding unacknowledged delivered
%% signals, the delivery time of the oldest: the silent-link check.
-spec unacked_since(state()) -> [{binary(), integer()}].
unacked_since(#st{entities = Entities}) ->
    [{Id, T} || #entity{id = Id, attached = true, out = Out} <- maps:values(Entities),
                {value, {_, _, T}} <- [queue:peek(Out)]].

%% @doc The entities currently attached (their connection is to this
%% instance, as far as the state knows).
-spec attached_ids(state()) -> [binary()].
attached_ids(#st{entities = Entities}) ->
    lists:sort([Id || #entity{id = Id, attached = true} <- maps:values(Entities)]).

%% @doc The last SignalID accepted from an HA entity (`<<>>' when none).
-spec last_accepted(state(), binary()) -> binary().
last_accepted(#st{entities = Entities}, EntityId) ->
    case Entities of
        #{EntityId := #entity{last_accepted = L}} -> L;
        #{} -> <<>>
    end.

%% @doc The SignalIDs accepted from an HA entity that its de-duplication
%% window holds, oldest first (the model's check of accepted signals).
-spec accepted_ids(state(), binary()) -> [binary()].
accepted_ids(#st{entities = Entities}, EntityId) ->
    case Entities of
        #{EntityId := #entity{seen_q = Q}} -> queue:to_list(Q);
        #{} -> []
    end.

%% @doc The signals delivered to an HA entity and not acknowledged, oldest
%% first, as stamped (Sequence and epoch) when they were routed.
-spec unacked(state(), binary()) -> [bil:signal()].
unacked(#st{entities = Entities}, EntityId) ->
    case Entities of
        #{EntityId := #entity{out = Out}} -> [Sig || {_, Sig, _} <- queue:to_list(Out)];
        #{} -> []
    end.
