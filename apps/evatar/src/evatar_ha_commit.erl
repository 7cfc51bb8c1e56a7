%% @doc Internal. Output commit of an active instance, pure: which of the
%% effects of `evatar_pairing_logic' go out now and which wait, and for
%% what. Every event applied gets the next version; with a standby it is
%% queued for shipping and every effect seen outside (a delivery, a report,
%% a reply, an Ack) waits in the outbox until the standby confirms that
%% version, so what a client sees is always in the standby's history.
%% Without one (`direct') effects go out at once; after a takeover or the
%% loss of the standby's node (`held') they wait until a majority accepted
%% the new configuration (`evatar_ha_core'), then all go out.
%%
%% ```
%%   logic effects --step/6--> timers, logs: now          (every mode)
%%                             the rest:  direct ---------------> out now
%%                                        held, replicated -> outbox[V]
%%   confirm(V) / release_all --> outbox[=< V] out, then the batched Acks
%%   flush --> replicated: {ship, Events};  direct: {acks, Acks}
%% '''
%% Entities are bound to their connection (`Conn', a pid in
%% `evatar_pairing') when an effect is held: released later, it must not
%% reach a connection that attached since. Nothing here holds a pid it
%% did not get as an argument, a timer or a clock.
-module(evatar_ha_commit).

-export([new/1, version/1, applied/2, confirmed/1, synced/1, pending/1, outbox_empty/1]).
-export([step/6, reply/4, report/3, confirm/2, release_all/1, flush/2, flush_maybe/3,
         shipped/1, unsync/1, synced_at/2, reset/1]).

-export_type([state/0, mode/0, effect/0, repl_event/0]).

%% One message per batch, at the latest every FLUSH_EVERY events.
-define(FLUSH_EVERY, 64).

-type mode() :: direct | held | replicated.
-type repl_event() :: {Version :: pos_integer(), NowMs :: integer(),
                       evatar_pairing_logic:event()}.
%% What the process does, in order. `{send, Conn, Msg}' is a message to a
%% connection bound when the effect was made; `{acks, Acks}' the batched
%% Acks for the entities' current connections; `{ship, Events}' the events
%% to the standby; `flush_later' asks for a {@link flush/2} once the
%% messages already waiting are handled.
-type effect() :: {deliver, binary(), bil:signal()}
                | {report, binary(), evatar:binding_report()}
                | {drop, binary(), evatar:drop_code(), binary()}
                | {start_timer, evatar_pairing_logic:timer_key(), non_neg_integer()}
                | {cancel_timer, evatar_pairing_logic:timer_key()}
                | {log, logger:level(), logger:report()}
                | {send, Conn :: term(), term()}
                | {reply_to, From :: term(), term()}
                | {acks, #{binary() => binary()}}
                | {ship, [repl_event()]}
                | flush_later.

-record(commit, {version = 0 :: non_neg_integer(),
                 confirmed = 0 :: non_neg_integer(),
                 synced = false :: boolean(),
                 repl = [] :: [repl_event()],
                 outbox = queue:new() :: queue:queue({non_neg_integer(), [effect()]}),
                 acks = #{} :: #{binary() => binary()},
                 unflushed = 0 :: non_neg_integer()}).
-opaque state() :: #commit{}.

%% @doc A commit at `Version' (0 for a new pairing; a standby's version
%% when it takes over).
-spec new(non_neg_integer()) -> state().
new(Version) -> #commit{version = Version}.

%% @doc The version of the last event applied.
-spec version(state()) -> non_neg_integer().
version(#commit{version = V}) -> V.

%% @doc A standby applied the events up to `Version'.
-spec applied(non_neg_integer(), state()) -> state().
applied(V, C) -> C#commit{version = V}.

%% @doc The highest version the standby confirmed.
-spec confirmed(state()) -> non_neg_integer().
confirmed(#commit{confirmed = C}) -> C.

%% @doc Whether the standby confirmed anything since it got its snapshot.
-spec synced(state()) -> boolean().
synced(#commit{synced = S}) -> S.

%% @doc Whether a flush has something to do.
-spec pending(state()) -> boolean().
pending(#commit{repl = [], acks = Acks}) -> map_size(Acks) > 0;
pending(#commit{}) -> true.

%% @doc Whether nothing waits in the outbox.
-spec outbox_empty(state()) -> boolean().
outbox_empty(#commit{outbox = Q}) -> queue:is_empty(Q).

%% @doc Applies the effects of one logic event (`Event' at `Now'): returns
%% the logic's reply (`ok' for events without one) and what goes out now.
%% `Conns' maps entity ids to their connections, for held effects.
-spec step(evatar_pairing_logic:event(), integer(), [evatar_pairing_logic:effect()],
           #{binary() => term()}, mode(), state()) -> {term(), [effect()], state()}.
step(Event, Now, Effects, Conns, Mode, #commit{version = V0} = C0) ->
    V = V0 + 1,
    C = C0#commit{version = V},
    case Mode of
        direct ->
            direct(Effects, ok, [], C);
        held ->
            {Reply, Now1, Held} = split(Effects, Conns, ok, [], []),
            {Reply, Now1, hold(V, Held, C)};
        replicated ->
            {Reply, Now1, Held} = split(Effects, Conns, ok, [], []),
            {Reply, Now1, hold(V, Held, C#commit{repl = [{V, Now, Event} | C#commit.repl]})}
    end.

%% @doc A call's reply: now in `direct' mode, else after the current version.
-spec reply(term(), term(), mode(), state()) -> {[effect()], state()}.
reply(From, Reply, direct, C) -> {[{reply_to, From, Reply}], C};
reply(From, Reply, _Mode, #commit{version = V} = C) -> {[], hold(V, [{reply_to, From, Reply}], C)}.

%% @doc Sends that change no state (the current Binding report to one
%% entity): they wait behind what is held, never overtaking an older report.
-spec report([effect()], mode(), state()) -> {[effect()], state()}.
report(Sends, _Mode, #commit{outbox = Q, version = V} = C) ->
    case queue:is_empty(Q) of
        true -> {Sends, C};
        false -> {[], hold(V, Sends, C)}
    end.

%% @doc The standby confirmed `Version': what was held for it goes out,
%% then the Acks.
-spec confirm(non_neg_integer(), state()) -> {[effect()], state()}.
confirm(Version, #commit{confirmed = Conf} = C) ->
    release(Version, C#commit{confirmed = max(Conf, Version), synced = true}, []).

%% @doc No standby any more, or the cluster accepted the configuration:
%% everything held goes out now.
-spec release_all(state()) -> {[effect()], state()}.
release_all(#commit{version = V} = C) ->
    {Out, C1} = release(V, C, []),
    {Out, C1#commit{repl = [], unflushed = 0}}.

%% @doc The batch: the queued events to the standby (`replicated'), the
%% Acks (`direct'), nothing while `held'.
-spec flush(mode(), state()) -> {[effect()], state()}.
flush(held, C) ->
    {[], C#commit{unflushed = 0}};
flush(direct, #commit{acks = Acks} = C) ->
    {[{acks, Acks} || map_size(Acks) > 0], C#commit{acks = #{}, unflushed = 0}};
flush(replicated, #commit{repl = []} = C) ->
    {[], C#commit{unflushed = 0}};
flush(replicated, #commit{repl = Repl} = C) ->
    {[{ship, lists:reverse(Repl)}], C#commit{repl = [], unflushed = 0}}.

%% @doc Flushes when the mailbox is empty (`QueueLen' 0) or every
%% FLUSH_EVERY events; else once the waiting messages are handled.
-spec flush_maybe(non_neg_integer(), mode(), state()) -> {[effect()], state()}.
flush_maybe(QueueLen, Mode, #commit{unflushed = N} = C) ->
    case pending(C) of
        false -> {[], C};
        true when QueueLen =:= 0; N >= ?FLUSH_EVERY -> flush(Mode, C);
        true when N =:= 0 -> {[flush_later], C#commit{unflushed = 1}};
        true -> {[], C#commit{unflushed = N + 1}}
    end.

%% @doc A snapshot went to the standby: it holds every event queued so far.
-spec shipped(state()) -> state().
shipped(C) -> C#commit{repl = [], unflushed = 0}.

%% @doc A new standby, or none: not in sync.
-spec unsync(state()) -> state().
unsync(C) -> C#commit{synced = false, repl = [], unflushed = 0}.

%% @doc A standby that is in sync at once, having confirmed `Version'
%% (the old active after a handover).
-spec synced_at(non_neg_integer(), state()) -> state().
synced_at(V, C) -> C#commit{synced = true, confirmed = V}.

%% @doc This instance stopped being the active (handed over): nothing it
%% held goes out any more.
-spec reset(state()) -> state().
reset(C) -> C#commit{outbox = queue:new(), repl = [], acks = #{}, unflushed = 0}.

%% ---------------------------------------------------------------------------

direct([{reply, Reply} | Rest], _Reply, Out, C) ->
    direct(Rest, Reply, Out, C);
direct([{accepted, EntityId, SignalId} | Rest], Reply, Out, #commit{acks = Acks} = C) ->
    direct(Rest, Reply, Out, C#commit{acks = Acks#{EntityId => SignalId}});
direct([E | Rest], Reply, Out, C) ->
    direct(Rest, Reply, [E | Out], C);
direct([], Reply, Out, C) ->
    {Reply, lists:reverse(Out), C}.

%% Timers and logs now, the rest held; deliveries and reports bound now to
%% the connection they were meant for.
split([{reply, Reply} | Rest], Conns, _Reply, Now, Held) ->
    split(Rest, Conns, Reply, Now, Held);
split([{Kind, _, _} = E | Rest], Conns, Reply, Now, Held)
  when Kind =:= start_timer; Kind =:= log ->
    split(Rest, Conns, Reply, [E | Now], Held);
split([{cancel_timer, _} = E | Rest], Conns, Reply, Now, Held) ->
    split(Rest, Conns, Reply, [E | Now], Held);
split([{Kind, EntityId, What} | Rest], Conns, Reply, Now, Held)
  when Kind =:= deliver; Kind =:= report ->
    Msg = case Kind of
              deliver -> {signal, What};
              report -> {bound, What}
          end,
    case Conns of
        #{EntityId := Conn} -> split(Rest, Conns, Reply, Now, [{send, Conn, Msg} | Held]);
        #{} -> split(Rest, Conns, Reply, Now, Held)
    end;
split([E | Rest], Conns, Reply, Now, Held) ->
    split(Rest, Conns, Reply, Now, [E | Held]);
split([], _Conns, Reply, Now, Held) ->
    {Reply, lists:reverse(Now), lists:reverse(Held)}.

hold(_V, [], C) -> C;
hold(V, Effects, #commit{outbox = Q} = C) -> C#commit{outbox = queue:in({V, Effects}, Q)}.

release(Version, #commit{outbox = Q} = C, Out) ->
    case queue:peek(Q) of
        {value, {V, Effects}} when V =< Version ->
            {Out1, C1} = absorb_acks(Effects, Out, C#commit{outbox = queue:drop(Q)}),
            release(Version, C1, Out1);
        _ ->
            #commit{acks = Acks} = C,
            {lists:reverse(Out, [{acks, Acks} || map_size(Acks) > 0]), C#commit{acks = #{}}}
    end.

absorb_acks([{accepted, EntityId, SignalId} | Rest], Out, #commit{acks = Acks} = C) ->
    absorb_acks(Rest, Out, C#commit{acks = Acks#{EntityId => SignalId}});
absorb_acks([E | Rest], Out, C) ->
    absorb_acks(Rest, [E | Out], C);
absorb_acks([], Out, C) ->
    {Out, C}.
