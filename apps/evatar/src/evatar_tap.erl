%% @doc The live signal tail of a pairing (docs/dashboard.md). The active
%% instance keeps a list of watchers; with none (`[]', the rule) a routed
%% event costs one match on the empty list in `evatar_pairing:step/2', so
%% nobody watching costs nothing measurable. With watchers, every event's
%% effects are turned into tail items (signals delivered, EVATAR's
%% refusals, timeouts and voided requests, drops, joins and leaves,
%% rebinds) and sent to each watcher whose filter takes them.
%%
%% A watcher never slows or grows the pairing: each has a window of
%% `?WINDOW' messages it has not acknowledged; beyond it the pairing counts
%% what it could not send, and the watcher's next acknowledgement brings a
%% `dropped' item with that count first. Watchers are monitored (removed
%% when they die), sent to with `nosuspend' (a busy distribution link
%% drops, never blocks), at most `?MAX_WATCHERS' per pairing
%% (`too_many_watchers'). An instance that stops being active sends its
%% watchers a `moved' item and forgets them; {@link handle/2} then follows
%% the pairing to its new active.
%%
%% The pairing side: {@link add/4}, {@link emit/5}, {@link acked/3},
%% {@link down/2}, {@link moved/3}. The watcher side: {@link watch/2},
%% {@link handle/2}, {@link unwatch/1}.
-module(evatar_tap).

-export([add/4, emit/5, acked/3, down/2, moved/3]).
-export([watch/2, handle/2, unwatch/1, filter/2, kinds/0, window/0]).

-export_type([watcher/0, filter/0, item/0, sub/0]).

%% Messages in flight to one watcher at most; it acknowledges every half.
-define(WINDOW, 256).
-define(MAX_WATCHERS, 16).
%% A signal's parameters in an item: at most this many, values cut.
-define(MAX_PARAMS, 8).
-define(MAX_VALUE, 200).
-define(RETRY_MS, 1000).

-record(w, {ref :: reference(),
            pid :: pid(),
            filter :: filter(),
            credit = ?WINDOW :: non_neg_integer(),
            dropped = 0 :: non_neg_integer()}).

-opaque watcher() :: #w{}.
%% `kinds': the item kinds wanted (every kind when absent); `entity': only
%% items from or to that entity id. `dropped' and `moved' items always pass.
-type filter() :: #{kinds => [binary()], entity => binary()}.
%% JSON-ready: binary keys' values are binaries, integers, `null' or lists.
-type item() :: #{kind := binary(), at := integer(), pairing := binary(), atom() => term()}.
-opaque sub() :: #{pairing := binary(), filter := filter(), ref := reference() | undefined,
                   pid := pid() | undefined, mon := reference() | undefined,
                   unacked := non_neg_integer()}.

%% ---------------------------------------------------------------------------
%% Filters
%% ---------------------------------------------------------------------------

%% @doc Every item kind, as the filter and the items spell them.
-spec kinds() -> [binary()].
kinds() ->
    [<<"request">>, <<"feedback">>, <<"progress">>, <<"sensor_data">>, <<"event">>,
     <<"error">>, <<"refusal">>, <<"timeout">>, <<"void">>, <<"late">>, <<"drop">>,
     <<"entity">>, <<"bindings">>].

%% @doc Messages in flight to one watcher at most (the window).
-spec window() -> pos_integer().
window() -> ?WINDOW.

%% @doc Checks a filter given as text: `Kinds' a comma-separated list of
%% kinds (empty: all), `Entity' an entity id (empty: all).
-spec filter(binary(), binary()) -> {ok, filter()} | {error, {bad_kind, binary()}}.
filter(Kinds, Entity) when is_binary(Kinds), is_binary(Entity) ->
    Wanted = [K || K <- binary:split(Kinds, <<",">>, [global, trim_all])],
    case [K || K <- Wanted, not lists:member(K, kinds())] of
        [Bad | _] ->
            {error, {bad_kind, Bad}};
        [] ->
            F0 = case Wanted of
                     [] -> #{};
                     _ -> #{kinds => lists:usort(Wanted)}
                 end,
            {ok, case Entity of
                     <<>> -> F0;
                     _ -> F0#{entity => Entity}
                 end}
    end.

passes(#{kind := K}, _) when K =:= <<"dropped">>; K =:= <<"moved">> ->
    true;
passes(Item, Filter) ->
    kind_ok(Item, Filter) andalso entity_ok(Item, Filter).

kind_ok(#{kind := K}, #{kinds := Ks}) -> lists:member(K, Ks);
kind_ok(_, #{}) -> true.

entity_ok(Item, #{entity := E}) ->
    maps:get(from_entity, Item, null) =:= E orelse maps:get(to_entity, Item, null) =:= E;
entity_ok(_, #{}) -> true.

%% ---------------------------------------------------------------------------
%% The pairing's side
%% ---------------------------------------------------------------------------

%% @doc Adds watcher `Pid' (monitored; its `DOWN' comes tagged
%% `evatar_tap_down'). Returns the reference its items carry.
-spec add(pid(), filter(), [watcher()], binary()) ->
          {ok, reference(), [watcher()]} | {error, too_many_watchers}.
add(_Pid, _Filter, Watchers, _Id) when length(Watchers) >= ?MAX_WATCHERS ->
    {error, too_many_watchers};
add(Pid, Filter, Watchers, _Id) ->
    Ref = erlang:monitor(process, Pid, [{tag, evatar_tap_down}]),
    {ok, Ref, [#w{ref = Ref, pid = Pid, filter = Filter} | Watchers]}.

%% @doc A watcher died.
-spec down(reference(), [watcher()]) -> [watcher()].
down(Ref, Watchers) ->
    lists:keydelete(Ref, #w.ref, Watchers).

%% @doc Sends the items of one event and its effects to every watcher
%% whose filter takes some. Called only with watchers.
-spec emit(binary(), term(), [term()], integer(), [watcher()]) -> [watcher()].
emit(Id, Event, Effects, Now, Watchers) ->
    case items(Id, Event, Effects, Now) of
        [] -> Watchers;
        Items -> [send(W, [I || I <- Items, passes(I, F)]) || #w{filter = F} = W <- Watchers]
    end.

send(W, []) ->
    W;
send(#w{credit = 0, dropped = D} = W, Items) ->
    W#w{dropped = D + length(Items)};
send(#w{ref = Ref, pid = Pid, credit = C, dropped = D} = W, Items) ->
    case erlang:send(Pid, {evatar_tap, Ref, Items}, [nosuspend, noconnect]) of
        ok -> W#w{credit = C - 1};
        _ -> W#w{dropped = D + length(Items)}
    end.

%% @doc The watcher acknowledged `N' messages: its credit comes back, and
%% what was dropped meanwhile is announced first.
-spec acked(reference(), non_neg_integer(), [watcher()]) -> [watcher()].
acked(Ref, N, Watchers) ->
    case lists:keyfind(Ref, #w.ref, Watchers) of
        #w{credit = C, dropped = 0} = W ->
            lists:keystore(Ref, #w.ref, Watchers, W#w{credit = min(?WINDOW, C + N)});
        #w{credit = C, dropped = D} = W ->
            Marker = #{kind => <<"dropped">>, count => D,
                       at => erlang:system_time(millisecond), pairing => null},
            W1 = send(W#w{credit = min(?WINDOW, C + N), dropped = 0}, [Marker]),
            lists:keystore(Ref, #w.ref, Watchers, W1);
        false ->
            Watchers
    end.

%% @doc This instance is no longer the active (`Role'): each watcher is
%% told and forgotten.
-spec moved(binary(), atom(), [watcher()]) -> [].
moved(Id, Role, Watchers) ->
    Item = #{kind => <<"moved">>, pairing => Id, role => atom_to_binary(Role),
             at => erlang:system_time(millisecond)},
    _ = [begin
             erlang:demonitor(Ref, [flush]),
             erlang:send(Pid, {evatar_tap, Ref, [Item]}, [nosuspend, noconnect])
         end || #w{ref = Ref, pid = Pid} <- Watchers],
    [].

%% The tail items of one event: what the pairing decided, in order.
items(Id, Event, Effects, Now) ->
    From = case Event of
               {signal, E, _} -> E;
               _ -> null
           end,
    Items = lists:filtermap(fun(Effect) -> item(Effect, From) end, Effects),
    %% One rebind reports to every entity: one item.
    {Bindings, Others} = lists:partition(fun(#{kind := K}) -> K =:= <<"bindings">> end, Items),
    [I#{at => Now, pairing => Id} || I <- Others ++ lists:sublist(Bindings, 1)].

item({deliver, To, #{origin := evatar, body := #{type := Type}} = S}, _From) ->
    Kind = case Type of
               <<"Timeout">> -> <<"timeout">>;
               <<"JoinTimeout">> -> <<"timeout">>;
               <<"ProviderGone">> -> <<"void">>;
               %% To a provider: the request it was working on was closed.
               <<"RequestClosed">> -> <<"void">>;
               %% An answer to no open request (late, twice, never asked).
               <<"NoOpenRequest">> -> <<"late">>;
               _ -> <<"refusal">>
           end,
    {true, (signal_fields(S))#{kind => Kind, from_entity => <<"EVATAR">>, to_entity => To,
                               code => Type, message => message(S)}};
item({deliver, To, #{context := Context} = S}, From) ->
    {true, (signal_fields(S))#{kind => context(Context), from_entity => From,
                               to_entity => To}};
item({drop, E, Code, Reason}, _From) ->
    {true, #{kind => <<"drop">>, to_entity => E, code => atom_to_binary(Code),
             message => Reason}};
item({report, E, #{bound := B, unbound := U}}, _From) ->
    {true, #{kind => <<"bindings">>, to_entity => E, bound => length(B),
             unbound => length(U)}};
item({log, _, #{what := What, entity := E} = R}, _From)
  when What =:= entity_joined; What =:= entity_left; What =:= registered;
       What =:= description_refused ->
    Extra = case R of
                #{reason := Reason} when is_binary(Reason) -> #{message => Reason};
                #{why := Why} when is_atom(Why) -> #{message => atom_to_binary(Why)};
                #{role := Role} when is_atom(Role) -> #{message => atom_to_binary(Role)};
                #{} -> #{}
            end,
    {true, Extra#{kind => <<"entity">>, what => atom_to_binary(What), from_entity => E}};
item(_, _From) ->
    false.

context(request) -> <<"request">>;
context(request_no_feedback) -> <<"request">>;
context(feedback) -> <<"feedback">>;
context(progress) -> <<"progress">>;
context(sensor_data) -> <<"sensor_data">>;
context(event) -> <<"event">>;
context(error) -> <<"error">>;
context(_) -> <<"error">>.

signal_fields(#{id := Id, sender := From, receiver := To, body := Body} = S) ->
    #{signal => Id, from => From, to => To,
      in_reply_to => null_if_undefined(maps:get(in_reply_to, S, undefined)),
      seq => null_if_undefined(maps:get(seq, S, undefined)),
      category => maps:get(category, Body, null), type => maps:get(type, Body, null),
      parameters => [[N, cut(V)] || {N, V} <- lists:sublist(maps:get(parameters, Body, []),
                                                             ?MAX_PARAMS)]}.

message(#{body := #{parameters := Ps}}) ->
    case lists:keyfind(<<"Message">>, 1, Ps) of
        {_, M} -> M;
        false -> null
    end.

cut(V) when is_binary(V), byte_size(V) > ?MAX_VALUE -> <<(binary:part(V, 0, ?MAX_VALUE))/binary, "...">>;
cut(V) -> V.

null_if_undefined(undefined) -> null;
null_if_undefined(V) -> V.

%% ---------------------------------------------------------------------------
%% The watcher's side
%% ---------------------------------------------------------------------------

%% @doc Makes the calling process a watcher of pairing `PairingId' (its
%% active, wherever it runs). Items come as messages that {@link handle/2}
%% turns into lists of items.
-spec watch(binary(), filter()) -> {ok, sub()} | {error, not_found | busy | too_many_watchers}.
watch(PairingId, Filter) when is_binary(PairingId), is_map(Filter) ->
    attach(#{pairing => PairingId, filter => Filter, ref => undefined, pid => undefined,
             mon => undefined, unacked => 0}).

attach(#{pairing := Id, filter := Filter} = Sub) ->
    case active_of(Id) of
        {ok, Pid} ->
            case call(Pid, {tap_watch, self(), Filter}) of
                {ok, Ref} ->
                    Mon = erlang:monitor(process, Pid),
                    {ok, Sub#{ref := Ref, pid := Pid, mon := Mon, unacked := 0}};
                {redirect, Active} when is_pid(Active), Active =/= Pid ->
                    case call(Active, {tap_watch, self(), Filter}) of
                        {ok, Ref} ->
                            Mon = erlang:monitor(process, Active),
                            {ok, Sub#{ref := Ref, pid := Active, mon := Mon, unacked := 0}};
                        _ -> {error, busy}
                    end;
                {redirect, _} -> {error, busy};
                {error, _} = Error -> Error
            end;
        {error, _} = Error ->
            Error
    end.

active_of(Id) ->
    case evatar_registry:whereis_name(Id) of
        undefined ->
            case [A || {_, #{role := active, active := A}} <- evatar:ha_locate(Id), is_pid(A)] of
                [A | _] -> {ok, A};
                [] -> {error, not_found}
            end;
        Pid ->
            {ok, Pid}
    end.

call(Pid, Request) ->
    try
        gen_statem:call(Pid, Request, 5000)
    catch
        exit:{timeout, _} -> {error, busy};
        exit:_ -> {error, not_found}
    end.

%% @doc Handles one message the watcher received: `{items, Items, Sub}'
%% for the tail's items (a `moved' item when the pairing's active changed,
%% an `unavailable' one while it has none), `ignore' for a message that is
%% not the tail's.
-spec handle(term(), sub()) -> {items, [item()], sub()} | ignore.
handle({evatar_tap, Ref, Items}, #{ref := Ref, pid := Pid, unacked := U} = Sub) ->
    U1 = U + 1,
    case U1 >= ?WINDOW div 2 of
        true ->
            Pid ! {evatar_tap_ack, Ref, U1},
            lost_if_moved(Items, Sub#{unacked := 0});
        false ->
            lost_if_moved(Items, Sub#{unacked := U1})
    end;
handle({'DOWN', Mon, process, _, _}, #{mon := Mon, pairing := Id} = Sub) ->
    {items, [#{kind => <<"moved">>, pairing => Id, role => <<"gone">>,
               at => erlang:system_time(millisecond)}], retry(Sub)};
handle({evatar_tap_retry, Id}, #{pairing := Id, ref := undefined} = Sub) ->
    case attach(Sub) of
        {ok, Sub1} ->
            {items, [#{kind => <<"attached">>, pairing => Id, node => atom_to_binary(
                                                                          node(maps:get(pid, Sub1))),
                       at => erlang:system_time(millisecond)}], Sub1};
        {error, _} ->
            {items, [], retry(Sub)}
    end;
handle(_Other, _Sub) ->
    ignore.

lost_if_moved(Items, Sub) ->
    case [I || #{kind := <<"moved">>} = I <- Items] of
        [] -> {items, Items, Sub};
        _ -> {items, Items, retry(Sub)}
    end.

retry(#{pairing := Id, mon := Mon} = Sub) ->
    _ = [erlang:demonitor(Mon, [flush]) || is_reference(Mon)],
    _ = erlang:send_after(?RETRY_MS, self(), {evatar_tap_retry, Id}),
    Sub#{ref := undefined, pid := undefined, mon := undefined, unacked := 0}.

%% @doc Stops watching.
-spec unwatch(sub()) -> ok.
unwatch(#{ref := Ref, pid := Pid, mon := Mon}) when is_pid(Pid) ->
    erlang:demonitor(Mon, [flush]),
    Pid ! {evatar_tap_unwatch, Ref},
    ok;
unwatch(#{}) ->
    ok.
