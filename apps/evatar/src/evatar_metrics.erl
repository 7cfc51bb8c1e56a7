%% @doc The node's counters for operators (`GET /metrics', docs/metrics.md):
%% OTP `counters' created when the evatar application starts, incremented
%% where things happen (a pairing's routing decisions, joins, takeovers,
%% fencing, the bridge's refusals) and rendered in the Prometheus text
%% format by {@link render/0}.
%%
%% Every label value comes from a fixed list below: a value outside it
%% counts as `other', so no client can add a series. The one exception is
%% the pairing id of the per-pairing series (`evatar_pairing_*'): ids of
%% pairings an operator created, for instances active on this node only, and
%% at most `metrics_max_pairings' of them (application env, default 1000;
%% the pairings over it count in the node's totals only, and
%% `evatar_metrics_pairings_unlabelled' says how many there are).
%%
%% This process owns the table of the per-pairing counters and removes a
%% pairing's entry when its process ends. An increment never talks to it:
%% `counters:add/3' on a reference the caller holds or reads from a
%% persistent term.
-module(evatar_metrics).
-behaviour(gen_server).

-export([start_link/0, init_counters/0, inc/2, inc/1, pairing/1, pairing_step/3,
         pairing_inc/3, add_collector/1, render/0, value/2, pairing_value/3,
         definitions/0]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-export_type([pairing_ref/0, sample/0]).

-define(NODE_KEY, {?MODULE, node}).
-define(COLLECTORS, {?MODULE, collectors}).
-define(TABLE, evatar_metrics_pairings).
-define(DEFAULT_MAX_PAIRINGS, 1000).

%% Counters and where each (metric, label value) is in them.
-type slots() :: {counters:counters_ref(), #{atom() => #{term() => pos_integer()}}}.
%% What a pairing counts on: the node's counters and its own (`undefined'
%% over the cap), held by the pairing so that counting reads no table;
%% `undefined' before it is active here.
-type pairing_ref() :: {slots(), slots() | undefined} | undefined.
%% A gauge sample from a collector: name, label pairs, value.
-type sample() :: {atom(), [{atom(), binary()}], number()}.
-type metric_type() :: counter | gauge.
-type definition() :: {Name :: atom(), metric_type(), Help :: binary(),
                       Label :: atom() | none, Values :: [atom() | binary()]}.

%% ---------------------------------------------------------------------------
%% What is counted
%% ---------------------------------------------------------------------------

-define(KINDS, [request, feedback, progress, error, sensor_data, request_no_feedback, event]).
-define(SIGNAL_REFUSALS, [<<"BadSender">>, <<"BadSignal">>, <<"DuplicateRequest">>,
                          <<"IdTooLong">>, <<"NoOpenRequest">>, <<"NotBound">>,
                          <<"NotDescribed">>, <<"TooManyRequests">>, <<"UnknownReceiver">>,
                          other]).
-define(JOIN_REFUSALS, [unknown_pairing, bad_credential, occupied, entity_exists,
                        too_many_entities, stale_epoch, fenced, not_active, busy, id_too_long,
                        reserved_id, other]).
-define(ACCEPT_REFUSALS, [<<"TooManyConnections">>, <<"RateLimited">>, <<"LockedOut">>, other]).
-define(HANDSHAKE_REFUSALS, [<<"UnknownPairing">>, <<"BadCredential">>, <<"IdTooLong">>,
                             <<"ReservedId">>, <<"Occupied">>, <<"EntityExists">>,
                             <<"TooManyEntities">>, <<"StaleEpoch">>, <<"Busy">>, <<"Fenced">>,
                             <<"NotActive">>, <<"LockedOut">>, <<"BadHandshake">>,
                             <<"HandshakeTimeout">>, <<"TlsHandshakeFailed">>, <<"Malformed">>,
                             <<"FrameTooLarge">>, other]).
-define(DROPS, [join_timeout, slow_consumer, silent_link, other]).
-define(TAKEOVERS, [active_silent, active_died, fenced, handover, other]).

%% @doc The node's metrics, in the order they are rendered (docs/metrics.md).
-spec definitions() -> [definition()].
definitions() ->
    [{evatar_signals_routed_total, counter,
      <<"Signals a pairing active on this node routed to their receiver, by context.">>,
      kind, ?KINDS},
     {evatar_signals_refused_total, counter,
      <<"Signals a pairing refused with an error signal to their sender, by error type.">>,
      code, ?SIGNAL_REFUSALS},
     {evatar_feedback_timeouts_total, counter,
      <<"Requests answered by EVATAR's Timeout feedback: no feedback within the "
        "pairing's feedback_timeout.">>, none, [none]},
     {evatar_late_feedback_total, counter,
      <<"Feedback or progress that answered no open request (late or never asked), "
        "dropped.">>, none, [none]},
     {evatar_joins_total, counter,
      <<"Joins and resumes accepted by a pairing on this node, by role and kind.">>,
      kind, [agent_join, avatar_join, agent_resume, avatar_resume]},
     {evatar_join_refusals_total, counter,
      <<"Joins and resumes refused, by reason (evatar:join_error()).">>,
      reason, ?JOIN_REFUSALS},
     {evatar_entities_dropped_total, counter,
      <<"Entities a pairing dropped or disconnected, by reason.">>, reason, ?DROPS},
     {evatar_takeovers_total, counter,
      <<"Instances on this node that took their pairing over (became active at a new "
        "epoch), by reason.">>, reason, ?TAKEOVERS},
     {evatar_fenced_total, counter,
      <<"Active instances on this node that fenced themselves (lost the cluster's majority, "
        "or the cluster refused their configuration).">>, none, [none]},
     {evatar_step_downs_total, counter,
      <<"Active instances on this node that stepped down for a newer instance.">>,
      none, [none]},
     {evatar_bridge_connections_accepted_total, counter,
      <<"Sockets the bridge's listeners accepted and admitted.">>, none, [none]},
     {evatar_bridge_connections_refused_total, counter,
      <<"Sockets the listeners' guards refused at once, by Refused code.">>,
      reason, ?ACCEPT_REFUSALS},
     {evatar_bridge_handshakes_refused_total, counter,
      <<"Handshakes the bridge refused, by Refused code.">>, reason, ?HANDSHAKE_REFUSALS}].

%% A pairing's own counters: rendered with a `pairing' label.
pairing_definitions() ->
    [{evatar_pairing_signals_routed_total, counter,
      <<"Signals this pairing routed while active on this node, by context.">>,
      kind, ?KINDS},
     {evatar_pairing_signals_refused_total, counter,
      <<"Signals this pairing refused while active on this node.">>, none, [none]},
     {evatar_pairing_feedback_timeouts_total, counter,
      <<"Requests of this pairing answered by EVATAR's Timeout feedback.">>, none, [none]},
     {evatar_pairing_joins_total, counter,
      <<"Joins and resumes this pairing accepted while active on this node.">>,
      none, [none]},
     {evatar_pairing_join_refusals_total, counter,
      <<"Joins and resumes this pairing refused while active on this node.">>,
      none, [none]}].

%% Gauges read when rendering.
gauge_definitions() ->
    [{evatar_pairing_instances, gauge,
      <<"Pairing instances on this node, by role.">>},
     {evatar_bridge_connections_open, gauge,
      <<"Connections the bridge's listeners hold now (admitted, not yet closed).">>},
     {evatar_metrics_pairings_unlabelled, gauge,
      <<"Active pairings on this node without per-pairing series (over "
        "metrics_max_pairings).">>},
     {evatar_data_dir_full, gauge,
      <<"1 while this node's data directory has no room for a catalogue change "
        "(creating and deleting pairings is refused), else 0.">>}].

%% ---------------------------------------------------------------------------
%% Counting
%% ---------------------------------------------------------------------------

%% @doc Creates the node's counters (at the evatar application's start;
%% again only when they do not exist yet, so counts survive a restart of
%% the application's tree).
-spec init_counters() -> ok.
init_counters() ->
    case persistent_term:get(?NODE_KEY, undefined) of
        undefined ->
            Index = index(definitions()),
            Ref = counters:new(slot_count(definitions()), [write_concurrency]),
            persistent_term:put(?NODE_KEY, {Ref, Index});
        _ ->
            ok
    end.

%% @doc Adds one to a node counter with no label.
-spec inc(atom()) -> ok.
inc(Name) ->
    inc(Name, none).

%% @doc Adds one to a node counter; a label value not in its list counts
%% as `other'.
-spec inc(atom(), term()) -> ok.
inc(Name, Label) ->
    case persistent_term:get(?NODE_KEY, undefined) of
        {Ref, Index} -> add(Ref, Index, Name, Label);
        undefined -> ok
    end.

%% Two small maps (metric, then label value): found without hashing.
add(Ref, Index, Name, Label) ->
    case Index of
        #{Name := #{Label := I}} -> counters:add(Ref, I, 1);
        #{Name := #{other := I}} -> counters:add(Ref, I, 1);
        #{} -> ok
    end.

slot(Index, Name, Label) ->
    #{Name := #{Label := I}} = Index,
    I.

%% @doc A node counter's value (tests, operators).
-spec value(atom(), term()) -> non_neg_integer().
value(Name, Label) ->
    {Ref, Index} = persistent_term:get(?NODE_KEY),
    counters:get(Ref, slot(Index, Name, Label)).

%% @doc A pairing's counter's value on this node, or 0 when it has none.
-spec pairing_value(evatar:pairing_id(), atom(), term()) -> non_neg_integer().
pairing_value(PairingId, Name, Label) ->
    case ets:lookup(?TABLE, PairingId) of
        [{_, _Pid, Ref}] -> counters:get(Ref, slot(pairing_index(), Name, Label));
        [] -> 0
    end.

%% @doc The counters of pairing `PairingId', whose active instance is the
%% calling process: made on first call, the same ones again after, and
%% `undefined' beyond `metrics_max_pairings'.
-spec pairing(evatar:pairing_id()) -> pairing_ref().
pairing(PairingId) ->
    case persistent_term:get(?NODE_KEY, undefined) of
        undefined ->
            undefined;
        Node ->
            case whereis(?MODULE) =/= undefined andalso
                gen_server:call(?MODULE, {pairing, PairingId, self()}) of
                {ok, Ref} -> {Node, {Ref, pairing_index()}};
                _ -> {Node, undefined}
            end
    end.

%% @doc Counts one step of a pairing: its event and the effects its logic
%% decided (evatar_pairing_logic:handle/3), on the node's counters and
%% the pairing's own.
-spec pairing_step(pairing_ref(), evatar_pairing_logic:event(),
                   [evatar_pairing_logic:effect()]) -> ok.
pairing_step({{Ref, Index}, Own}, Event, Effects) when element(1, Event) =:= signal;
                                                       element(1, Event) =:= timeout ->
    count_effects(Effects, Ref, Index, Own);
pairing_step(_PRef, _Event, _Effects) ->
    ok.

%% Deliveries EVATAR made itself (refusals, timeouts) carry `origin'.
count_effects([{deliver, _, #{origin := _}} | Rest], Ref, Index, PRef) ->
    count_effects(Rest, Ref, Index, PRef);
count_effects([{deliver, _, #{context := Kind}} | Rest], Ref, Index, PRef) ->
    add(Ref, Index, evatar_signals_routed_total, Kind),
    ok = own_inc(PRef, evatar_pairing_signals_routed_total, Kind),
    count_effects(Rest, Ref, Index, PRef);
count_effects([{log, _, #{what := signal_refused, code := Code}} | Rest], Ref, Index, PRef) ->
    add(Ref, Index, evatar_signals_refused_total, Code),
    ok = own_inc(PRef, evatar_pairing_signals_refused_total, none),
    count_effects(Rest, Ref, Index, PRef);
count_effects([{log, _, #{what := feedback_timeout}} | Rest], Ref, Index, PRef) ->
    add(Ref, Index, evatar_feedback_timeouts_total, none),
    ok = own_inc(PRef, evatar_pairing_feedback_timeouts_total, none),
    count_effects(Rest, Ref, Index, PRef);
count_effects([{log, _, #{what := late_feedback}} | Rest], Ref, Index, PRef) ->
    add(Ref, Index, evatar_late_feedback_total, none),
    count_effects(Rest, Ref, Index, PRef);
count_effects([{drop, _, Code, _} | Rest], Ref, Index, PRef) ->
    add(Ref, Index, evatar_entities_dropped_total, Code),
    count_effects(Rest, Ref, Index, PRef);
count_effects([_ | Rest], Ref, Index, PRef) ->
    count_effects(Rest, Ref, Index, PRef);
count_effects([], _Ref, _Index, _PRef) ->
    ok.

%% @doc Adds one to a pairing's own counter (nothing for `undefined').
-spec pairing_inc(pairing_ref(), atom(), term()) -> ok.
pairing_inc({_Node, Own}, Name, Label) ->
    own_inc(Own, Name, Label);
pairing_inc(undefined, _Name, _Label) ->
    ok.

own_inc({Ref, Index}, Name, Label) ->
    add(Ref, Index, Name, Label);
own_inc(undefined, _Name, _Label) ->
    ok.

%% @doc Registers a module whose `Function()' returns gauge samples
%% ({@link sample()}) when the metrics are rendered: how an application
%% that evatar does not depend on (agent_bridge) adds its gauges.
-spec add_collector({module(), atom()}) -> ok.
add_collector({M, F} = MF) when is_atom(M), is_atom(F) ->
    Old = persistent_term:get(?COLLECTORS, []),
    case lists:member(MF, Old) of
        true -> ok;
        false -> persistent_term:put(?COLLECTORS, Old ++ [MF])
    end.

%% ---------------------------------------------------------------------------
%% Rendering
%% ---------------------------------------------------------------------------

%% @doc Every metric in the Prometheus text exposition format (version 0.0.4).
-spec render() -> iodata().
render() ->
    {Ref, Index} = persistent_term:get(?NODE_KEY),
    Node = [family(Name, Type, Help,
                   [{labels(Label, V), counters:get(Ref, slot(Index, Name, V))}
                    || V <- Values])
            || {Name, Type, Help, Label, Values} <- definitions()],
    Pairings = lists:sort([{Id, R} || {Id, _Pid, R} <- ets:tab2list(?TABLE)]),
    PIndex = pairing_index(),
    PerPairing = [family(Name, Type, Help,
                         [{[{pairing, Id} | labels(Label, V)],
                           counters:get(R, slot(PIndex, Name, V))}
                          || {Id, R} <- Pairings, V <- Values])
                  || {Name, Type, Help, Label, Values} <- pairing_definitions()],
    Samples = gauges(),
    Gauges = [family(Name, Type, Help, [{L, V} || {N, L, V} <- Samples, N =:= Name])
              || {Name, Type, Help} <- gauge_definitions()],
    [Node, PerPairing, Gauges].

labels(none, none) -> [];
labels(Label, Value) -> [{Label, Value}].

family(Name, Type, Help, Samples) ->
    N = atom_to_binary(Name),
    [<<"# HELP ">>, N, $\s, escape_help(Help), $\n,
     <<"# TYPE ">>, N, $\s, atom_to_binary(Type), $\n,
     [[N, label_set(Labels), $\s, number(V), $\n] || {Labels, V} <- Samples]].

label_set([]) ->
    [];
label_set(Labels) ->
    [${, lists:join($,, [[atom_to_binary(K), $=, $", escape_label(text(V)), $"]
                          || {K, V} <- Labels]), $}].

text(V) when is_atom(V) -> atom_to_binary(V);
text(V) when is_binary(V) -> V.

number(V) when is_integer(V) -> integer_to_binary(V);
number(V) when is_float(V) -> float_to_binary(V, [short]).

%% The format's escapes: in HELP backslash and newline; in a label value
%% also the double quote.
escape_help(Text) ->
    escape(Text, false).

escape_label(Text) ->
    escape(Text, true).

escape(Text, Quote) ->
    << <<(case C of
              $\\ -> <<"\\\\">>;
              $\n -> <<"\\n">>;
              $" when Quote -> <<"\\\"">>;
              _ -> <<C>>
          end)/binary>> || <<C>> <= Text >>.

%% The gauges of this application and of the registered collectors; a
%% collector that fails adds nothing (the scrape still answers).
gauges() ->
    Live = [{Id, Pid, R} || {Id, Pid, R, _Epoch} <- evatar_registry:roles(),
                            is_process_alive(Pid)],
    Instances = [{evatar_pairing_instances, [{role, R}],
                  length([x || {_, _, R1} <- Live, R1 =:= R])}
                 || R <- [active, standby, fenced, starting]],
    Unlabelled = {evatar_metrics_pairings_unlabelled, [],
                  length([x || {Id, Pid, active} <- Live,
                               ets:match_object(?TABLE, {Id, Pid, '_'}) =:= []])},
    Collected = lists:append([collect(MF) || MF <- persistent_term:get(?COLLECTORS, [])]),
    Full = {evatar_data_dir_full, [], case evatar_catalogue:disk_full() of
                                          false -> 0;
                                          _ -> 1
                                      end},
    Instances ++ [Unlabelled, Full | Collected].

collect({M, F}) ->
    try M:F() of
        Samples when is_list(Samples) -> Samples
    catch
        _:_ -> []
    end.

index(Definitions) ->
    {Index, _Next} =
        lists:foldl(fun({Name, _, _, _, Values}, {Acc, N}) ->
                            Slots = maps:from_list(lists:zip(Values,
                                                             lists:seq(N, N + length(Values) - 1))),
                            {Acc#{Name => Slots}, N + length(Values)}
                    end, {#{}, 1}, Definitions),
    Index.

slot_count(Definitions) ->
    lists:sum([length(Values) || {_, _, _, _, Values} <- Definitions]).

pairing_index() ->
    index(pairing_definitions()).

%% ---------------------------------------------------------------------------
%% The table of per-pairing counters
%% ---------------------------------------------------------------------------

%% @doc Starts the owner of the per-pairing counters, registered as
%% `evatar_metrics'.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    gen_server:start_link({local, ?MODULE}, ?MODULE, [], []).

%% @private
-spec init([]) -> {ok, #{}}.
init([]) ->
    ok = init_counters(),
    _ = ets:new(?TABLE, [named_table, protected, set, {read_concurrency, true}]),
    {ok, #{}}.

%% @private
-spec handle_call(term(), gen_server:from(), #{reference() => evatar:pairing_id()}) ->
          {reply, term(), #{reference() => evatar:pairing_id()}}.
handle_call({pairing, Id, Pid}, _From, Mons) ->
    case ets:lookup(?TABLE, Id) of
        [{Id, Pid, Ref}] ->
            {reply, {ok, Ref}, Mons};
        Found ->
            Max = application:get_env(evatar, metrics_max_pairings, ?DEFAULT_MAX_PAIRINGS),
            case Found =/= [] orelse ets:info(?TABLE, size) < Max of
                true ->
                    Ref = counters:new(slot_count(pairing_definitions()), []),
                    true = ets:insert(?TABLE, {Id, Pid, Ref}),
                    Mon = erlang:monitor(process, Pid),
                    {reply, {ok, Ref}, Mons#{Mon => Id}};
                false ->
                    {reply, none, Mons}
            end
    end.

%% @private
-spec handle_cast(term(), M) -> {noreply, M}.
handle_cast(_Msg, Mons) ->
    {noreply, Mons}.

%% @private
-spec handle_info(term(), #{reference() => evatar:pairing_id()}) ->
          {noreply, #{reference() => evatar:pairing_id()}}.
handle_info({'DOWN', Mon, process, Pid, _}, Mons) ->
    case maps:take(Mon, Mons) of
        {Id, Mons1} ->
            %% Only this process's entry: a restarted instance may have
            %% registered under the same id since.
            true = ets:match_delete(?TABLE, {Id, Pid, '_'}),
            {noreply, Mons1};
        error ->
            {noreply, Mons}
    end;
handle_info(_Msg, Mons) ->
    {noreply, Mons}.
