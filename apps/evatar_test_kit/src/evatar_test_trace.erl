%% @doc Test support: waiting for what the product reports, not for time.
%% EVATAR's processes log structured reports (`#{what => taken_over,
%% pairing => P, ...}', docs/architecture.md section 7); a trace collects
%% those of the nodes it is attached to, in the order they reach it, and a
%% test waits for the report it expects:
%%
%% ```
%% {ok, T} = evatar_test_trace:start(),
%% ok = evatar_test_trace:attach(T, Node),          % or attach(T) for this node
%% Mark = evatar_test_trace:mark(T),
%% ok = evatar_test_cluster:kill(C, 1),
%% #{node := N} = evatar_test_trace:wait(T, #{what => taken_over, pairing => P},
%%                                       #{since => Mark}),
%% ok = evatar_test_trace:stop(T).
%% '''
%%
%% A match is a map (every key it has must be in the report with an equal
%% value; the atom `'_'' matches any value) or a predicate on the report.
%% `since' (a mark, default 0: every report the trace holds) lets a wait
%% ignore what came before the step it is about. The wait's timeout only
%% guards against a hang (default evatar_test_time:guard()): a case never
%% depends on it being short.
%%
%% The handler is a logger handler (id `evatar_test_trace') that sends
%% each report with a `what' to the trace's collector process; it never
%% blocks the process that logs. Attaching lowers the node's primary level
%% to `info' when it is higher (a node of the harness cluster logs `info'
%% already) and gives the `default' handler the old level, so the node's
%% own log does not change; detaching puts both back. One trace per node
%% at a time: attaching again replaces the earlier handler.
%%
%% The model is snabbkaffe's `?tp' and `?block_until' (klarna/snabbkaffe),
%% with the product's reports as trace points.
-module(evatar_test_trace).

-export([start/0, stop/1, attach/1, attach/2, detach/2, mark/1, wait/2, wait/3,
         events/1, events/2, events/3, matches/2]).
-export([install/1, uninstall/0, log/2, adding_handler/1, removing_handler/1]).

-export_type([trace/0, match/0, event/0, wait_opts/0]).

-opaque trace() :: pid().
-type match() :: #{atom() => term()} | fun((map()) -> boolean()).
%% seq: its place in the trace (1 for the first); node: the node that
%% logged it; level: its logger level; report: the report itself.
-type event() :: #{seq := pos_integer(), node := node(), level := logger:level(),
                   report := map()}.
%% since: only events after this mark; node: only events of this node;
%% timeout: the hang guard; count: wait for this many matching events and
%% return them all (default 1, which returns the event itself); what:
%% names the wait in its failure.
-type wait_opts() :: #{since => non_neg_integer(), node => node(), timeout => timeout(),
                       count => pos_integer(), what => term()}.

-define(HANDLER, evatar_test_trace).
-define(CALL, 15000).

%% ---------------------------------------------------------------------------
%% The trace
%% ---------------------------------------------------------------------------

%% @doc Starts an empty trace: a collector process of its own, not linked
%% to the caller (Common Test runs init_per_testcase and the case in
%% different processes); stop/1 ends it.
-spec start() -> {ok, trace()}.
start() ->
    {ok, spawn(fun() -> collect(#{events => [], count => 0, waiters => [], nodes => []}) end)}.

%% @doc Detaches the trace from every node it is attached to and ends it.
-spec stop(trace()) -> ok.
stop(T) ->
    Nodes = call(T, nodes),
    _ = [detach(T, N) || N <- Nodes],
    Ref = erlang:monitor(process, T),
    T ! stop,
    receive {'DOWN', Ref, process, T, _} -> ok end.

%% @doc Attaches the trace to this node.
-spec attach(trace()) -> ok.
attach(T) ->
    attach(T, node()).

%% @doc Attaches the trace to Node (this kit must be on its code path, as
%% it is on the harness cluster's nodes): its reports from now on reach
%% the trace.
-spec attach(trace(), node()) -> ok | {error, term()}.
attach(T, Node) ->
    case on(Node, install, [T]) of
        ok -> call(T, {attached, Node});
        Error -> Error
    end.

%% @doc Removes the trace's handler from Node and puts its levels back.
-spec detach(trace(), node()) -> ok | {error, term()}.
detach(T, Node) ->
    _ = call(T, {detached, Node}),
    on(Node, uninstall, []).

%% @doc The trace's current end: a wait with `since => mark(T)' considers
%% only what is reported after this call.
-spec mark(trace()) -> non_neg_integer().
mark(T) ->
    call(T, mark).

%% @doc The first event matching Match (wait/3 with no options).
-spec wait(trace(), match()) -> event().
wait(T, Match) ->
    wait(T, Match, #{}).

%% @doc Waits for an event matching Match after `since' and returns it (or
%% the first `count' of them, as a list). The event may already be in the
%% trace: a wait does not race the step that causes it. When the guard
%% expires, fails with `{trace_timeout, #{what, waited_ms, seen}}', seen
%% being the `what's of the last 50 events, to read what happened
%% instead.
-spec wait(trace(), match(), wait_opts()) -> event() | [event()].
wait(T, Match, Opts) ->
    Since = maps:get(since, Opts, 0),
    Count = maps:get(count, Opts, 1),
    Timeout = maps:get(timeout, Opts, evatar_test_time:guard()),
    Ref = make_ref(),
    T ! {wait, self(), Ref, {maps:get(node, Opts, '_'), Match}, Since, Count},
    Start = erlang:monotonic_time(millisecond),
    receive
        {Ref, Events} when Count =:= 1 -> hd(Events);
        {Ref, Events} -> Events
    after Timeout ->
            T ! {cancel, Ref},
            receive {Ref, _} -> ok after 0 -> ok end,
            Seen = [{N, maps:get(what, R)} || #{node := N, report := R} <- lists:sublist(
                                                                            lists:reverse(events(T)), 50)],
            erlang:error({trace_timeout, #{what => maps:get(what, Opts, Match),
                                           waited_ms => erlang:monotonic_time(millisecond) - Start,
                                           seen => lists:reverse(Seen)}})
    end.

%% @doc Every event of the trace, in order.
-spec events(trace()) -> [event()].
events(T) ->
    call(T, events).

%% @doc The events of the trace that match Match, in order.
-spec events(trace(), match()) -> [event()].
events(T, Match) ->
    events(T, Match, #{}).

%% @doc The events matching Match, with the `since' and `node' of
%% wait/3: for a case that checks, at its end, that something was never
%% reported.
-spec events(trace(), match(), #{since => non_neg_integer(), node => node()}) -> [event()].
events(T, Match, Opts) ->
    Since = maps:get(since, Opts, 0),
    Selector = {maps:get(node, Opts, '_'), Match},
    [E || #{seq := Q} = E <- events(T), Q > Since, selects(Selector, E)].

%% @doc Whether Report matches Match.
-spec matches(match(), map()) -> boolean().
matches(Match, Report) when is_function(Match, 1) ->
    Match(Report) =:= true;
matches(Match, Report) when is_map(Match) ->
    maps:fold(fun(_, _, false) -> false;
                 (K, '_', true) -> is_map_key(K, Report);
                 (K, V, true) -> maps:find(K, Report) =:= {ok, V}
              end, true, Match).

%% ---------------------------------------------------------------------------
%% The collector
%% ---------------------------------------------------------------------------

collect(#{events := Es, count := N, waiters := Ws, nodes := Nodes} = S) ->
    receive
        {?MODULE, Node, Level, Report} ->
            E = #{seq => N + 1, node => Node, level => Level, report => Report},
            collect(S#{events := [E | Es], count := N + 1, waiters := serve(E, Ws)});
        {wait, Pid, Ref, Match, Since, Count} ->
            Found = [E || #{seq := Q} = E <- lists:reverse(Es), Q > Since, selects(Match, E)],
            case length(Found) >= Count of
                true ->
                    Pid ! {Ref, lists:sublist(Found, Count)},
                    collect(S);
                false ->
                    collect(S#{waiters := [{Pid, Ref, Match, Count, lists:reverse(Found)} | Ws]})
            end;
        {cancel, Ref} ->
            collect(S#{waiters := [W || {_, R, _, _, _} = W <- Ws, R =/= Ref]});
        {call, Pid, Ref, mark} ->
            Pid ! {Ref, N},
            collect(S);
        {call, Pid, Ref, events} ->
            Pid ! {Ref, lists:reverse(Es)},
            collect(S);
        {call, Pid, Ref, nodes} ->
            Pid ! {Ref, Nodes},
            collect(S);
        {call, Pid, Ref, {attached, Node}} ->
            Pid ! {Ref, ok},
            collect(S#{nodes := lists:usort([Node | Nodes])});
        {call, Pid, Ref, {detached, Node}} ->
            Pid ! {Ref, ok},
            collect(S#{nodes := lists:delete(Node, Nodes)});
        stop ->
            ok
    end.

%% Whether event E is of the node and matches.
selects({Node, Match}, #{node := N, report := R}) ->
    (Node =:= '_' orelse Node =:= N) andalso matches(Match, R).

%% A new event for the waiters: those it completes are answered.
serve(E, Ws) ->
    lists:filtermap(fun({Pid, Ref, Match, Count, Found} = W) ->
                            case selects(Match, E) of
                                false ->
                                    {true, W};
                                true when length(Found) + 1 >= Count ->
                                    Pid ! {Ref, Found ++ [E]},
                                    false;
                                true ->
                                    {true, {Pid, Ref, Match, Count, Found ++ [E]}}
                            end
                    end, Ws).

call(T, Request) ->
    Ref = erlang:monitor(process, T),
    T ! {call, self(), Ref, Request},
    receive
        {Ref, Reply} ->
            erlang:demonitor(Ref, [flush]),
            Reply;
        {'DOWN', Ref, process, T, Why} ->
            erlang:error({trace_gone, Why})
    after ?CALL ->
            erlang:error(trace_silent)
    end.

%% ---------------------------------------------------------------------------
%% On a traced node
%% ---------------------------------------------------------------------------

on(Node, F, A) when Node =:= node() ->
    apply(?MODULE, F, A);
on(Node, F, A) ->
    case rpc:call(Node, ?MODULE, F, A, ?CALL) of
        {badrpc, Why} -> {error, {badrpc, Node, Why}};
        Result -> Result
    end.

%% @private Installs the handler on this node for trace T.
-spec install(trace()) -> ok.
install(T) ->
    _ = uninstall(),
    #{level := Primary} = logger:get_primary_config(),
    Lowered = logger:compare_levels(Primary, info) =:= gt,
    Default = case logger:get_handler_config(default) of
                  {ok, #{level := DL}} -> DL;
                  _ -> none
              end,
    ok = logger:add_handler(?HANDLER, ?MODULE,
                            #{level => info,
                              config => #{collector => T, primary => Primary,
                                          default_level => Default, lowered => Lowered}}),
    case Lowered of
        true ->
            _ = Default =/= none andalso
                logger:set_handler_config(default, level, stricter(Default, Primary)),
            ok = logger:set_primary_config(level, info);
        false ->
            ok
    end.

%% @private Removes the handler from this node, putting its levels back.
-spec uninstall() -> ok | {error, term()}.
uninstall() ->
    case logger:get_handler_config(?HANDLER) of
        {ok, #{config := #{lowered := true, primary := Primary, default_level := Default}}} ->
            ok = logger:remove_handler(?HANDLER),
            ok = logger:set_primary_config(level, Primary),
            _ = Default =/= none andalso logger:set_handler_config(default, level, Default),
            ok;
        {ok, _} ->
            logger:remove_handler(?HANDLER);
        {error, _} ->
            ok
    end.

stricter(A, B) ->
    case logger:compare_levels(A, B) of
        lt -> B;
        _ -> A
    end.

%% @private
-spec adding_handler(logger:handler_config()) -> {ok, logger:handler_config()}.
adding_handler(Config) ->
    {ok, Config}.

%% @private
-spec removing_handler(logger:handler_config()) -> ok.
removing_handler(_Config) ->
    ok.

%% @private The handler: a report with a `what' goes to the collector,
%% never suspending the process that logs (a busy or absent connection to
%% the collector's node drops the event).
-spec log(logger:log_event(), logger:handler_config()) -> ok.
log(#{msg := {report, #{what := _} = Report}, level := Level},
    #{config := #{collector := T}}) ->
    _ = erlang:send(T, {?MODULE, node(), Level, Report}, [noconnect, nosuspend]),
    ok;
log(_Event, _Config) ->
    ok.
