%% @doc How the cost of a pairing's large operations grows (issue 16):
%% voiding open requests when their provider goes, binding and re-binding
%% many components, resuming a session with many unacknowledged signals;
%% each at three sizes a factor 10 apart, with the growth per 10x and the
%% exponent fitted over the sizes, side by side with the algorithms they
%% replaced where those finish (the old binding is the test oracle
%% apps/bil/test/bil_binding_old.erl; the old pairing logic is compiled
%% from git, commit ?OLD_COMMIT). Then, on this node over real TCP
%% sockets, the round trips of other pairings while one pairing does the
%% largest case. Not part of the product; bench/COMPLEXITY.md has figures.
-module(complexity_bench).

-export([main/0, main/1, concurrent_only/1]).

-type option() :: quick | no_old | no_concurrent | {log, logger:level()}
                | {tables, [void | bind | bind_any | rebind | resume]}.

%% The last commit with the quadratic voiding, the old oracle's source.
-define(OLD_COMMIT, "ccb6f43").
-define(P, <<"big">>).
-define(VA, <<"va">>).
-define(AV, <<"av">>).
-define(CRED_VA, <<"bench-va-credential">>).
-define(CRED_AV, <<"bench-av-credential">>).
-define(REQUESTER, <<"Requester">>).
-define(TARGET, <<"Target">>).
%% The old algorithms only up to these sizes (beyond: minutes to hours).
-define(OLD_MAX_VOID, 10000).
-define(OLD_MAX_BIND, 10000).
-define(BIG_LIMITS, #{max_open_requests => 1000000, max_consumes => 1000000,
                     max_binding_report => 1 bsl 30}).

%% ---------------------------------------------------------------------------
%% Entry points
%% ---------------------------------------------------------------------------

%% @equiv main([])
-spec main() -> ok.
main() -> main([]).

%% @doc Runs the benchmark and prints its tables. `quick': sizes 10 times
%% smaller; `no_old': without the old algorithms; `no_concurrent': without
%% the round trips of other pairings over TCP; `{tables, Names}': only
%% those tables (void, bind, bind_any, rebind, resume).
-spec main([option()]) -> ok.
main(Options) ->
    ok = logger:set_primary_config(level, warning),
    Quick = lists:member(quick, Options),
    Scale = case Quick of true -> 10; false -> 1 end,
    Old = case lists:member(no_old, Options) of
              true -> none;
              false -> load_old()
          end,
    io:format("Complexity benchmark: OTP ~s, ~b schedulers, ~s~n",
              [erlang:system_info(otp_release), erlang:system_info(schedulers_online),
               erlang:system_info(system_architecture)]),
    io:format("ms: wall time of the one operation (median of 3 runs below 1 s, else one run);~n"
              "x10: time at this size / time at a tenth of it (linear ~~10, n log n ~~13,~n"
              "quadratic ~~100); exponent k: least-squares fit of time ~~ n^k over the sizes~n"),
    Requests = [N div Scale || N <- [1000, 10000, 100000]],
    Components = [N div Scale || N <- [100, 1000, 10000]],
    Tables = proplists:get_value(tables, Options, [void, bind, bind_any, rebind, resume]),
    Table = fun(Name, Title, Unit, Sizes, Measure, OldMax) ->
                    _ = [table(Title, Unit, Sizes, Measure, Old, OldMax)
                         || lists:member(Name, Tables)],
                    ok
            end,
    Table(void, "Voiding: an Avatar with N open requests to it leaves (its Bye)",
          "open requests", Requests, fun(N, M) -> void_ms(M, N) end, ?OLD_MAX_VOID),
    Table(bind, "Binding: bil:bind/1, N provider components and 1.7 N Consumes in one bucket",
          "components", Components, fun(N, M) -> bind_ms(M, N) end, ?OLD_MAX_BIND),
    Table(bind_any, "Binding, adversarial: N providers, 9 in 10 offering `any' for the parameter; "
          "1.7 N Consumes each requiring a different value of it",
          "components", Components, fun(N, M) -> bind_any_ms(M, N) end, 1000),
    Table(rebind, "Re-binding: the pairing's describe event (the Avatar re-describes), N components",
          "components", Components, fun(N, M) -> rebind_ms(M, N) end, ?OLD_MAX_BIND),
    Table(resume, "Resuming: an HA session with N delivered signals not acknowledged",
          "unacked", Requests, fun(N, M) -> resume_ms(M, N) end, ?OLD_MAX_VOID),
    _ = [concurrent(lists:last(Requests), lists:last(Components))
         || not lists:member(no_concurrent, Options)],
    ok.

%% @doc Only the round trips of other pairings during the largest case.
-spec concurrent_only([option()]) -> ok.
concurrent_only(Options) ->
    ok = logger:set_primary_config(level, proplists:get_value(log, Options, warning)),
    Scale = case lists:member(quick, Options) of true -> 10; false -> 1 end,
    concurrent(100000 div Scale, 10000 div Scale),
    ok.

%% ---------------------------------------------------------------------------
%% Tables
%% ---------------------------------------------------------------------------

table(Title, Unit, Sizes, Measure, Old, OldMax) ->
    io:format("~n== ~s ==~n~-14s ~9s ~5s ~9s ~5s | ~10s ~5s ~10s ~5s | ~7s~n",
              [Title, Unit, "new ms", "x10", "new Mred", "x10", "old ms", "x10", "old Mred",
               "x10", "old/new"]),
    Rows = [begin
                New = Measure(N, new),
                OldR = case Old of
                           none -> undefined;
                           _ when N > OldMax -> undefined;
                           _ -> Measure(N, Old)
                       end,
                {N, New, OldR}
            end || N <- Sizes],
    lists:foldl(fun({N, {NewMs, NewRed} = New, OldR}, Prev) ->
                        {OldMs, OldRed} = case OldR of
                                              undefined -> {undefined, undefined};
                                              _ -> OldR
                                          end,
                        {{PNewMs, PNewRed}, {POldMs, POldRed}} =
                            case Prev of
                                {PN, {A, B}, {C, D}} when N =:= PN * 10 -> {{A, B}, {C, D}};
                                {PN, {A, B}, undefined} when N =:= PN * 10 ->
                                    {{A, B}, {undefined, undefined}};
                                _ -> {{undefined, undefined}, {undefined, undefined}}
                            end,
                        io:format("~-14b ~9s ~5s ~9s ~5s | ~10s ~5s ~10s ~5s | ~7s~n",
                                  [N, ms(NewMs), ratio(NewMs, PNewMs), mred(NewRed),
                                   ratio(NewRed, PNewRed), ms(OldMs), ratio(OldMs, POldMs),
                                   mred(OldRed), ratio(OldRed, POldRed), ratio(OldMs, NewMs)]),
                        {N, New, OldR}
                end, none, Rows),
    io:format("fitted exponent k (time ~~ n^k): new ~s (reductions ~s), old ~s (reductions ~s)~n",
              [exponent([{N, T} || {N, {T, _}, _} <- Rows]),
               exponent([{N, R} || {N, {_, R}, _} <- Rows]),
               exponent([{N, T} || {N, _, {T, _}} <- Rows]),
               exponent([{N, R} || {N, _, {_, R}} <- Rows])]).

ms(undefined) -> "-";
ms(T) -> io_lib:format("~.1f", [T]).

mred(undefined) -> "-";
mred(R) -> io_lib:format("~.2f", [R / 1.0e6]).

ratio(A, B) when is_number(A), is_number(B), B > 0 -> io_lib:format("~.1f", [A / B]);
ratio(_, _) -> "".

%% Least-squares slope of log t against log n.
exponent(Points) when length(Points) >= 2 ->
    Xs = [math:log(N) || {N, _} <- Points],
    Ys = [math:log(max(T, 0.001)) || {_, T} <- Points],
    K = length(Points),
    Mx = lists:sum(Xs) / K,
    My = lists:sum(Ys) / K,
    Slope = lists:sum([(X - Mx) * (Y - My) || {X, Y} <- lists:zip(Xs, Ys)])
        / lists:sum([(X - Mx) * (X - Mx) || X <- Xs]),
    io_lib:format("~.2f", [Slope]);
exponent(_) ->
    "-".

%% {Wall ms, reductions} of F, each run in a fresh process (no heap left
%% by the previous run): the median of 3 runs when one takes under 1 s.
%% Reductions count the work done whatever the machine's load and GC.
time_ms(F) ->
    {Ms, _} = First = isolated(F),
    case Ms < 1000 of
        true ->
            Runs = lists:sort([First, isolated(F), isolated(F)]),
            lists:nth(2, Runs);
        false ->
            First
    end.

isolated(F) ->
    {Pid, Ref} = spawn_monitor(fun() ->
                                       {reductions, R0} = process_info(self(), reductions),
                                       {Us, _} = timer:tc(F),
                                       {reductions, R1} = process_info(self(), reductions),
                                       exit({done, Us / 1000, R1 - R0})
                               end),
    receive
        {'DOWN', Ref, process, Pid, {done, Ms, Red}} -> {Ms, Red};
        {'DOWN', Ref, process, Pid, Why} -> error(Why)
    end.

%% ---------------------------------------------------------------------------
%% The old algorithms
%% ---------------------------------------------------------------------------

%% The old binding is the tests' oracle; the old pairing logic is compiled
%% from git under another module name, calling the old binding. Run from
%% the repository's root (the Makefile does).
load_old() ->
    {ok, Root} = file:get_cwd(),
    case compile:file(filename:join(Root, "apps/bil/test/bil_binding_old.erl"),
                      [binary, return_errors]) of
        {ok, bil_binding_old, Bin} ->
            {module, _} = code:load_binary(bil_binding_old, "bil_binding_old.erl", Bin),
            case old_logic(Root) of
                {ok, Mod} -> #{logic => Mod, bind => fun bil_binding_old:bind/1};
                {error, Why} ->
                    io:format("NOTE: no old pairing logic (~p): old voiding, re-binding and "
                              "resuming not shown~n", [Why]),
                    #{bind => fun bil_binding_old:bind/1}
            end;
        Error ->
            io:format("NOTE: cannot compile the old binding (~p): old figures not shown~n",
                      [Error]),
            none
    end.

%% evatar_pairing_logic at ?OLD_COMMIT, renamed evatar_pairing_logic_old
%% and calling the old binding: the old logic as it ran.
old_logic(Root) ->
    Cmd = "git -C '" ++ Root ++ "' show " ++ ?OLD_COMMIT
        ++ ":apps/evatar/src/evatar_pairing_logic.erl 2>/dev/null",
    case os:cmd(Cmd) of
        "%%" ++ _ = Source0 ->
            Source = lists:foldl(fun({From, To}, Acc) -> string:replace(Acc, From, To, all) end,
                                 Source0,
                                 [{"-module(evatar_pairing_logic).",
                                   "-module(evatar_pairing_logic_old)."},
                                  {"bil:bind(", "bil_binding_old:bind("}]),
            Dir = filename:join(Root, "_build/bench/old"),
            File = filename:join(Dir, "evatar_pairing_logic_old.erl"),
            ok = filelib:ensure_dir(File),
            ok = file:write_file(File, unicode:characters_to_binary(Source)),
            case compile:file(File, [binary, return_errors]) of
                {ok, Mod, Bin} ->
                    {module, Mod} = code:load_binary(Mod, File, Bin),
                    {ok, Mod};
                Error ->
                    {error, Error}
            end;
        _ ->
            {error, no_git_history}
    end.

logic(new) -> evatar_pairing_logic;
logic(#{logic := Mod}) -> Mod.

%% ---------------------------------------------------------------------------
%% The operations
%% ---------------------------------------------------------------------------

%% A VA whose one component requests from the Avatar's one; N requests
%% open (the feedback timeout is long); the Avatar leaves.
void_ms(Which, N) ->
    Mod = logic(Which),
    St0 = pairing(Mod, #{}),
    St1 = describe(Mod, ?VA, va([{?REQUESTER, [], [svc(<<"Light">>, [])]}]), St0),
    St2 = describe(Mod, ?AV, av([{?TARGET, [svc(<<"Light">>, [])], []}]), St1),
    St3 = lists:foldl(fun(I, St) ->
                              {St_, _} = Mod:handle({signal, ?VA, request(I)}, 1000, St),
                              St_
                      end, St2, lists:seq(1, N)),
    N = maps:get(pending, Mod:stats(St3)),
    time_ms(fun() ->
                    {St4, _} = Mod:handle({leave, ?AV, left}, 2000, St3),
                    0 = maps:get(pending, Mod:stats(St4))
            end).

bind_ms(new, N) ->
    Ds = [av(providers(N)), va(consumers(N))],
    time_ms(fun() -> bil:bind(Ds) end);
bind_ms(#{bind := Bind}, N) ->
    Ds = [av(providers(N)), va(consumers(N))],
    time_ms(fun() -> Bind(Ds) end).

bind_any_ms(new, N) ->
    Ds = [av(any_providers(N)), va(any_consumers(N))],
    time_ms(fun() -> bil:bind(Ds) end);
bind_any_ms(#{bind := Bind}, N) ->
    Ds = [av(any_providers(N)), va(any_consumers(N))],
    time_ms(fun() -> Bind(Ds) end).

%% The shape where `any' defeats the value index: most devices accept any
%% unit, every consumer names its own, so every consumer sees nearly
%% every provider as a candidate (issue 16's follow-up). A second required
%% value shared by a fraction f of the providers (a room) is not this
%% shape: it costs f x P per consumer, see bench/COMPLEXITY.md.
any_providers(N) ->
    [{<<"dev", (integer_to_binary(I))/binary>>,
      [svc(<<"Switch">>, [{<<"Unit">>, case I rem 10 of 0 -> dev(I); _ -> <<"any">> end},
                          {<<"Room">>, room(I)}])],
      []} || I <- lists:seq(1, N)].

any_consumers(N) ->
    [{<<"ctl", (integer_to_binary(I))/binary>>, [],
      [svc(<<"Switch">>, [{<<"Unit">>, dev(I)}])
       | [svc(<<"Switch">>, [{<<"Unit">>, dev(N + I)}, {<<"Room">>, <<"no">>}])
          || I rem 10 < 7]]} || I <- lists:seq(1, N)].

%% The VA consumes; the Avatar described with N components re-describes
%% itself with one more: the pairing checks it and binds again.
rebind_ms(Which, N) ->
    Mod = logic(Which),
    St0 = pairing(Mod, #{}),
    St1 = describe(Mod, ?VA, va(consumers(N)), St0),
    St2 = describe(Mod, ?AV, av(providers(N)), St1),
    Again = av(providers(N + 1)),
    time_ms(fun() -> describe(Mod, ?AV, Again, St2) end).

%% An HA VA with N delivered signals not acknowledged resumes.
resume_ms(Which, N) ->
    Mod = logic(Which),
    St1 = pairing(Mod, #{max_unacked_out => N + 1}, {join, agent, ?VA, ?CRED_VA, <<"s-va">>}),
    St2 = describe(Mod, ?VA, va([{?REQUESTER, [svc(<<"Light">>, [])], []}]), St1),
    St3 = describe(Mod, ?AV, av([{?TARGET, [], [svc(<<"Light">>, [])]}]), St2),
    St4 = lists:foldl(fun(I, St) ->
                              Event = (request(I))#{context => event, sender => ?TARGET,
                                                    receiver => ?REQUESTER},
                              {St_, _} = Mod:handle({signal, ?AV, Event}, 1000, St),
                              St_
                      end, St3, lists:seq(1, N)),
    {St5, _} = Mod:handle({detach, ?VA}, 1500, St4),
    time_ms(fun() ->
                    {_, Effects} = Mod:handle({resume, agent, ?VA, ?CRED_VA, <<"s-va">>, 0, 1},
                                              2000, St5),
                    N = length([E || {deliver, _, _} = E <- Effects])
            end).

pairing(Mod, Extra) ->
    pairing(Mod, Extra, {join, agent, ?VA, ?CRED_VA}).

%% The pairing limits (max_open_requests, max_consumes, max_binding_report, documented in
%% docs/protocol.md section 7) are raised to the sizes measured; the old logic
%% had none.
limits(evatar_pairing_logic) -> ?BIG_LIMITS;
limits(_Old) -> #{}.

pairing(Mod, Extra0, JoinVa) ->
    Extra = maps:merge(limits(Mod), Extra0),
    {ok, Config} = Mod:config(maps:merge(#{agent_credential => ?CRED_VA,
                                           avatar_credential => ?CRED_AV,
                                           feedback_timeout => 3600000,
                                           join_timeout => 3600000}, Extra)),
    St = Mod:new(?P, Config),
    {St1, _} = Mod:handle(JoinVa, 0, St),
    {St2, _} = Mod:handle({join, avatar, ?AV, ?CRED_AV}, 0, St1),
    St2.

describe(Mod, Id, Description, St) ->
    {St1, Effects} = Mod:handle({describe, Id, Description}, 500, St),
    [ok] = [R || {reply, R} <- Effects],
    St1.

request(I) ->
    #{id => <<"r", (integer_to_binary(I))/binary>>, context => request, sender => ?REQUESTER,
      receiver => ?TARGET, in_reply_to => undefined, timestamp => 1, seq => undefined,
      epoch => undefined, body => svc(<<"Light">>, [])}.

svc(Type, Params) -> #{category => <<"Actuator">>, type => Type, parameters => Params}.

%% The shape of the issue's home (6,590 components, 11,031 Consumes): many
%% devices of one kind, told apart by a parameter; each consumer names its
%% device, some also a room, some offer `any'.
providers(N) ->
    [{<<"dev", (integer_to_binary(I))/binary>>,
      [svc(<<"Switch">>, [{<<"Device">>, dev(I)}, {<<"Room">>, room(I)},
                          {<<"Dimmable">>, yes_no(I)}])],
      []} || I <- lists:seq(1, N)].

consumers(N) ->
    [{<<"ctl", (integer_to_binary(I))/binary>>, [],
      [svc(<<"Switch">>, [{<<"Device">>, dev(I)}])
       | [svc(<<"Switch">>, [{<<"Device">>, dev((I * 7) rem N + 1)}, {<<"Room">>, room(I)}])
          || I rem 10 < 7]]} || I <- lists:seq(1, N)].

dev(I) -> <<"d", (integer_to_binary(I))/binary>>.
room(I) -> <<"room", (integer_to_binary(I rem 20))/binary>>.
yes_no(I) when I rem 2 =:= 0 -> <<"yes">>;
yes_no(_) -> <<"no">>.

va(Components) -> description(?VA, agent, Components).
av(Components) -> description(?AV, avatar, Components).

description(Id, Type, Components) ->
    #{entity_id => Id, api_name => <<"BENCH">>, entity_type => Type, context => <<"Bench">>,
      components => [#{id => C, services => S, consumes => U} || {C, S, U} <- Components]}.

%% ---------------------------------------------------------------------------
%% Other pairings during the largest case, on a real node over TCP
%% ---------------------------------------------------------------------------

-define(PROBES, 4).

%% Probe pairings (a VA and an Avatar each, over TCP through agent_bridge)
%% do request round trips in a loop, before and while one pairing, driven
%% through the evatar API in this node, voids N open requests and re-binds
%% C components.
concurrent(N, C) ->
    io:format("~n== Other pairings' round trips while one pairing does the largest case ==~n"
              "~b probe pairings over TCP (agent_bridge_client, loopback) doing requests "
              "back to back;~nthe big pairing driven through the evatar API in this node~n",
              [?PROBES]),
    ok = application:set_env(agent_bridge, listeners, [], [{persistent, true}]),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = agent_bridge:start_listener(complexity_bench,
                                          #{ip => {127, 0, 0, 1}, port => 0}),
    {ok, Addr} = agent_bridge:address(complexity_bench),
    Probes = [probe(Addr, I) || I <- lists:seq(1, ?PROBES)],
    Idle = measure(Probes, fun() -> timer:sleep(3000) end),
    report("idle (3 s)", Idle, undefined),
    {ok, _} = evatar:create_pairing(?P, ?BIG_LIMITS#{agent_credential => ?CRED_VA,
                                                     avatar_credential => ?CRED_AV,
                                                     feedback_timeout => 3600000,
                                                     join_timeout => 3600000}),
    Va = entity(agent, ?VA, ?CRED_VA, va([{?REQUESTER, [], [svc(<<"Light">>, [])]} | consumers(C)])),
    Av = entity(avatar, ?AV, ?CRED_AV, av([{?TARGET, [svc(<<"Light">>, [])], []} | providers(C)])),
    call(Va, fun(S) -> [ok = evatar:send(S, request(I)) || I <- lists:seq(1, N)], ok end),
    wait_pending(N),
    Void = measure(Probes, fun() -> call(Av, fun evatar:leave/1) end),
    report(io_lib:format("Avatar leaves: ~b requests voided, ~b components unbound", [N, C]),
           Void, op_ms(Void)),
    Av2 = entity(avatar, ?AV, ?CRED_AV, av(providers(C))),
    Rebind = measure(Probes, fun() ->
                                     call(Av2, fun(S) -> evatar:describe(S, av(providers(C + 1))) end)
                             end),
    report(io_lib:format("Avatar re-describes: ~b components bound again", [C]), Rebind,
           op_ms(Rebind)),
    ok = evatar:delete_pairing(?P),
    _ = [exit(P, kill) || {P, _} <- Probes],
    ok.

%% A process holding a joined, described entity of the big pairing,
%% running what it is asked to with its session.
entity(Role, Id, Cred, Description) ->
    Parent = self(),
    Pid = spawn(fun() ->
                        {ok, S} = evatar:join(?P, Role, Id, Cred),
                        ok = evatar:describe(S, Description),
                        Parent ! {ready, self()},
                        entity_loop(S)
                end),
    receive {ready, Pid} -> Pid after 600000 -> error(entity_not_ready) end.

entity_loop(S) ->
    receive
        {run, From, F} -> From ! {ran, self(), F(S)}, entity_loop(S);
        _ -> entity_loop(S)
    end.

call(Pid, F) ->
    Pid ! {run, self(), F},
    receive {ran, Pid, R} -> R after 600000 -> error(timeout) end.

wait_pending(N) ->
    case evatar:stats(?P) of
        {ok, #{pending := N}} -> ok;
        _ -> timer:sleep(100), wait_pending(N)
    end.

%% One probe pairing: a VA requesting and an Avatar answering, over TCP.
probe(Addr, I) ->
    Id = <<"probe", (integer_to_binary(I))/binary>>,
    {ok, _} = evatar:create_pairing(Id, #{agent_credential => ?CRED_VA,
                                          avatar_credential => ?CRED_AV}),
    Opts = fun(Role, E, Cred) -> #{pairing => Id, role => Role, entity_id => E,
                                    credential => Cred} end,
    Parent = self(),
    Answerer = spawn_link(fun() ->
                             {ok, A} = agent_bridge_client:connect(
                                         [Addr], Opts(avatar, ?AV, ?CRED_AV)),
                             ok = agent_bridge_client:describe(
                                    A, av([{?TARGET, [svc(<<"Light">>, [])], []}])),
                             Parent ! {answering, self()},
                             answer(A)
                     end),
    receive {answering, Answerer} -> ok after 10000 -> error(probe_not_ready) end,
    Requester = spawn_link(fun() ->
                              {ok, V} = agent_bridge_client:connect(
                                          [Addr], Opts(agent, ?VA, ?CRED_VA)),
                              %% The schema wants a Service in every Component.
                              ok = agent_bridge_client:describe(
                                     V, va([{?REQUESTER, [svc(<<"Panel">>, [])],
                                             [svc(<<"Light">>, [])]}])),
                              wait_bound(V),
                              Parent ! {requesting, self()},
                              probe_loop(V, idle, [])
                      end),
    receive {requesting, Requester} -> ok after 10000 -> error(probe_not_ready) end,
    {Requester, Answerer}.

wait_bound(V) ->
    receive
        {agent_bridge, V, {binding, #{bound := [_ | _]}}} -> ok
    after 10000 -> error(probe_not_bound)
    end.

answer(A) ->
    receive
        {agent_bridge, A, {closed, Why}} ->
            exit({answerer_closed, Why});
        {agent_bridge, A, {signal, #{context := request, id := Id, sender := From,
                                     receiver := To, body := Body}}} ->
            ok = agent_bridge_client:send(A, #{context => feedback, sender => To,
                                               receiver => From, in_reply_to => Id,
                                               body => Body}),
            answer(A);
        _ ->
            answer(A)
    end.

%% Round trips back to back while measuring; the samples go to whoever
%% asked when told to stop. Other messages (reports) are dropped.
probe_loop(V, idle, _) ->
    receive
        {start, _From} -> probe_loop(V, running, []);
        {agent_bridge, V, {closed, Why}} -> exit({probe_closed, Why});
        _ -> probe_loop(V, idle, [])
    end;
probe_loop(V, running, Samples) ->
    receive
        {stop, From} ->
            From ! {samples, self(), Samples},
            probe_loop(V, idle, []);
        {agent_bridge, V, {closed, Why}} ->
            exit({probe_closed, Why});
        {agent_bridge, V, _} ->
            probe_loop(V, running, Samples)
    after 0 ->
            T0 = erlang:monotonic_time(microsecond),
            case agent_bridge_client:request(V, #{sender => ?REQUESTER, receiver => ?TARGET,
                                                  body => svc(<<"Light">>, [])}, 60000) of
                {ok, _} -> ok;
                {error, closed} ->
                    receive {agent_bridge, V, {closed, Why}} -> exit({probe_closed, Why})
                    after 1000 -> exit({probe_closed, unknown})
                    end
            end,
            T1 = erlang:monotonic_time(microsecond),
            probe_loop(V, running, [{T0, (T1 - T0) / 1000} | Samples])
    end.

%% Runs Op while the probes run; returns the samples and Op's interval.
measure(Probes, Op) ->
    _ = [P ! {start, self()} || {P, _} <- Probes],
    timer:sleep(300),
    T0 = erlang:monotonic_time(microsecond),
    _ = Op(),
    T1 = erlang:monotonic_time(microsecond),
    timer:sleep(300),
    _ = [P ! {stop, self()} || {P, _} <- Probes],
    Samples = lists:append([receive {samples, P, S} -> S after 120000 -> [] end
                            || {P, _} <- Probes]),
    #{samples => [Ms || {T, Ms} <- Samples, T + Ms * 1000 >= T0, T =< T1],
      all => [Ms || {_, Ms} <- Samples], op => {T0, T1}}.

op_ms(#{op := {T0, T1}}) -> (T1 - T0) / 1000.

report(What, #{samples := During, all := All}, OpMs) ->
    Xs = case OpMs of
             undefined -> All;
             _ -> During
         end,
    Sorted = lists:sort(Xs),
    case Sorted of
        [] ->
            io:format("~-62s no round trip completed~n", [What]);
        _ ->
            P = fun(Q) -> lists:nth(max(1, round(Q * length(Sorted))), Sorted) end,
            io:format("~-62s op ~8s ms; round trips ~6b: p50 ~.2f  p99 ~.2f  max ~.2f ms~n",
                      [What, ms(OpMs), length(Sorted), P(0.5), P(0.99), lists:last(Sorted)])
    end.
