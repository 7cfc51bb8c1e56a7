%% EUnit and PropEr tests of the catalogue's pure rules: merging two
%% nodes' catalogues, the winner of two writes, who restores a pairing.
-module(evatar_catalogue_rules_tests).

%% Both headers define LET: PropEr's is not used here.
-include_lib("proper/include/proper.hrl").
-undef(LET).
-include_lib("eunit/include/eunit.hrl").

-define(R, evatar_catalogue_rules).

cfg() -> #{agent_credential => <<"a">>, avatar_credential => <<"b">>}.

live(Id, V) -> {Id, V, {live, cfg(), a@h}}.

%% A write made after seeing another (a higher counter) wins, whatever the
%% clocks say; two writes made apart at one counter: a tombstone over a
%% live entry, then the greater node name; never the wall clock.
versions_test() ->
    V1 = ?R:next_version(none, 1000, a@h),
    ?assertEqual({1, 1000, a@h}, V1),
    V2 = ?R:next_version(V1, 5, b@h),
    ?assert(?R:wins(live(<<"p">>, V2), live(<<"p">>, V1))),
    ?assert(?R:wins({<<"p">>, V2, deleted}, live(<<"p">>, V1))),
    %% Same counter: the node name, not the later clock.
    ?assert(?R:wins(live(<<"p">>, {3, 9, b@h}), live(<<"p">>, {3, 10, a@h}))),
    %% Same counter: a tombstone, whatever the node names and clocks.
    ?assert(?R:wins({<<"p">>, {3, 1, a@h}, deleted}, live(<<"p">>, {3, 10, b@h}))),
    ?assertNot(?R:wins(live(<<"p">>, {3, 10, b@h}), {<<"p">>, {3, 1, a@h}, deleted})),
    %% A tombstone of an older counter loses to a write made after it.
    ?assert(?R:wins(live(<<"p">>, {4, 0, a@h}), {<<"p">>, {3, 99, b@h}, deleted})).

%% A node changes the catalogue only while it hears a majority; a cluster
%% of one always does, and in a cluster of two either node goes on alone.
may_change_test() ->
    ?assert(?R:may_change(3, true)),
    ?assertNot(?R:may_change(3, false)),
    ?assertNot(?R:may_change(5, false)),
    ?assert(?R:may_change(2, false)),
    ?assert(?R:may_change(1, true)).

%% A deletion made during a partition wins over the older live entry on
%% the other side; an entry only one side has is kept.
merge_partition_test() ->
    Ours = [live(<<"p">>, {1, 10, a@h}), live(<<"only-ours">>, {1, 11, a@h})],
    Theirs = [{<<"p">>, {2, 20, c@h}, deleted}, live(<<"only-theirs">>, {1, 12, c@h})],
    Merged = ?R:merge(Ours, Theirs),
    ?assertEqual([<<"only-ours">>, <<"only-theirs">>, <<"p">>], [Id || {Id, _, _} <- Merged]),
    ?assertMatch({_, _, deleted}, lists:keyfind(<<"p">>, 1, Merged)),
    ?assertEqual([{<<"p">>, {2, 20, c@h}, deleted}, live(<<"only-theirs">>, {1, 12, c@h})],
                 ?R:changed(Ours, Theirs)),
    ?assertEqual([], ?R:changed(Merged, Ours)).

%% A node that runs an instance of a pairing whose creation has not
%% reached its catalogue yet (it took over from the home node that created
%% it and died) deletes it with the first version it can write. That
%% tombstone, written after the creation, wins over the live entry when it
%% arrives later, in either order, and on the node that comes back with the
%% live entry on disc (ha_SUITE restart_with_changed_catalogue); also when
%% the deleting node's clock is far behind the creating node's.
blind_deletion_test() ->
    blind_deletion(1000, 1100),
    blind_deletion(1000, -86400000).

blind_deletion(CreatedAt, DeletedAt) ->
    Created = live(<<"p">>, ?R:next_version(none, CreatedAt, c@h)),
    Deleted = {<<"p">>, ?R:next_version(none, DeletedAt, a@h), deleted},
    ?assertEqual([Deleted], ?R:merge([Created], [Deleted])),
    ?assertEqual([Deleted], ?R:merge([Deleted], [Created])),
    ?assertEqual([Deleted], ?R:changed([Created], [Deleted])),
    ?assertEqual([], ?R:changed([Deleted], [Created])),
    ?assertEqual([<<"p">>], ?R:to_stop(?R:merge([Created], [Deleted]), [<<"p">>])).

%% The home node restores its pairing; without it, the next alive node of
%% the ring after the home does; nobody when nobody is alive.
owner_test() ->
    Nodes = [a@h, b@h, c@h],
    ?assertEqual(b@h, ?R:owner(b@h, Nodes, Nodes)),
    ?assertEqual(c@h, ?R:owner(b@h, Nodes, [a@h, c@h])),
    ?assertEqual(a@h, ?R:owner(c@h, Nodes, [a@h, b@h])),
    ?assertEqual(none, ?R:owner(c@h, Nodes, [])),
    %% A home that is no longer configured (a renamed node).
    ?assertEqual(a@h, ?R:owner(old@h, Nodes, [a@h])).

%% Only what this node owns and nobody runs is started; only deleted
%% pairings that run here are stopped.
start_stop_test() ->
    E = [{<<"mine">>, {1, 1, a@h}, {live, cfg(), a@h}},
         {<<"running">>, {1, 1, a@h}, {live, cfg(), a@h}},
         {<<"theirs">>, {1, 1, b@h}, {live, cfg(), b@h}},
         {<<"dead">>, {2, 1, a@h}, deleted}],
    View = {[a@h, b@h], [a@h, b@h]},
    ?assertEqual([{<<"mine">>, cfg()}], ?R:to_start(E, a@h, View, [<<"running">>])),
    ?assertEqual([<<"dead">>], ?R:to_stop(E, [<<"dead">>, <<"running">>])).

%% An instance that stepped down (a newer instance, a stale claim) did not
%% give up: its pairing, left without instances, is restored; one that
%% crashed did (its restart limit decides).
gave_up_test() ->
    ?assertNot(?R:gave_up({shutdown, {newer_instance, 'n2@h', 3}})),
    ?assertNot(?R:gave_up({shutdown, stale_claim})),
    ?assertNot(?R:gave_up(normal)),
    ?assertNot(?R:gave_up(shutdown)),
    ?assert(?R:gave_up({badarg, []})),
    ?assert(?R:gave_up(killed)).

%% Merging is commutative, associative and idempotent: catalogues
%% exchanged in any order end equal.
merge_converges_test() ->
    ok = evatar_test_proper:check(prop_merge(), 300).

%% Whatever the nodes' clocks say, the same writes exchanged the same way
%% end with the same winner: a history of creates and deletes on three
%% nodes (each written as evatar_catalogue does, from what that node holds),
%% with catalogues sent between them, replayed with the clocks of the
%% writes changed, picks the same write for every id.
clocks_decide_nothing_test() ->
    ok = evatar_test_proper:check(prop_clocks_decide_nothing(), 300).

prop_clocks_decide_nothing() ->
    ?FORALL({Steps, Skew}, {list(step()), list(integer())},
            begin
                Clocks = fun(I) -> lists:nth(1 + I rem max(1, length(Skew)), [0 | Skew]) end,
                strip(replay(Steps, fun(_I) -> 0 end)) =:= strip(replay(Steps, Clocks))
            end).

step() ->
    oneof([{write, oneof([a@h, b@h, c@h]), oneof([<<"p1">>, <<"p2">>]),
            oneof([create, delete, blind_delete])},
           {send, oneof([a@h, b@h, c@h]), oneof([a@h, b@h, c@h])}]).

%% Each write's clock is Clock(its index): the same writes, other clocks.
replay(Steps, Clock) ->
    Nodes = #{a@h => [], b@h => [], c@h => []},
    {Final, _} = lists:foldl(fun(Step, {Cats, I}) -> {step(Step, Clock(I), Cats), I + 1} end,
                             {Nodes, 0}, Steps),
    lists:foldl(fun(Cat, Acc) -> ?R:merge(Acc, Cat) end, [], maps:values(Final)).

step({send, From, To}, _Wall, Cats) ->
    Cats#{To := ?R:merge(maps:get(To, Cats), maps:get(From, Cats))};
step({write, Node, Id, Kind}, Wall, Cats) ->
    Cat = maps:get(Node, Cats),
    Current = lists:keyfind(Id, 1, Cat),
    Value = case {Kind, Current} of
                {create, false} -> {live, cfg(), Node};
                {create, {_, _, deleted}} -> {live, cfg(), Node};
                {delete, {_, _, {live, _, _}}} -> deleted;
                %% A node running an instance it has no entry of.
                {blind_delete, false} -> deleted;
                _ -> none
            end,
    case Value of
        none ->
            Cats;
        _ ->
            V = ?R:next_version(case Current of false -> none; {_, V0, _} -> V0 end, Wall, Node),
            Cats#{Node := ?R:merge(Cat, [{Id, V, Value}])}
    end.

strip(Entries) ->
    [{Id, C, N, Value} || {Id, {C, _Wall, N}, Value} <- Entries].

prop_merge() ->
    ?FORALL({A, B, C}, {catalogue(), catalogue(), catalogue()},
            begin
                AB = ?R:merge(A, B),
                AB =:= ?R:merge(B, A)
                    andalso ?R:merge(AB, C) =:= ?R:merge(A, ?R:merge(B, C))
                    andalso ?R:merge(AB, AB) =:= AB
                    andalso ?R:merge(AB, ?R:changed(A, B)) =:= AB
            end).

catalogue() ->
    proper_types:bind(list(entry()),
                      fun(Entries) ->
                              maps:values(maps:from_list([{Id, E} || {Id, _, _} = E <- Entries]))
                      end, false).

entry() ->
    proper_types:bind(
      {oneof([<<"p1">>, <<"p2">>, <<"p3">>]), range(1, 4), range(1, 3), oneof([a@h, b@h])},
      %% One value per version, as a real write makes.
      fun({Id, C, T, N}) ->
              {Id, {C, T, N}, case erlang:phash2({Id, C, T, N}, 2) of
                                  0 -> deleted;
                                  1 -> {live, cfg(), N}
                              end}
      end, false).

%% ---------------------------------------------------------------------------
%% The reconcile loop
%% ---------------------------------------------------------------------------

pid(N) -> list_to_pid("<0." ++ integer_to_list(N) ++ ".0>").

%% The facts of node a@h, in a cluster of a@h and b@h that hears a
%% majority, at monotonic time 100000.
facts(Entries, Roles) ->
    #{self => a@h, entries => Entries, roles => Roles, configured => [a@h, b@h],
      alive => [a@h, b@h], connected => [b@h], majority => true, size => 2,
      alone_ms => 30000, now_ms => 100000, wall_ms => 7}.

%% The memory of a@h started at `Started', which has b@h's catalogue.
mem(Started) ->
    {[{push, b@h}], M} = ?R:received(b@h, true, ?R:new(Started)),
    M.

mine(Id) -> {Id, {1, 1, a@h}, {live, cfg(), a@h}}.

%% One whole look: each step's effects, then the next step with the room
%% (`ok' or `full') and the connected peers' answers (`Answers', given
%% the nodes asked) as the process would get them; the effects of all
%% steps, the questions asked, and the memory.
run(Facts, M, Room, Answers) ->
    run(?R:look(Facts, M), Facts, Room, Answers, [], []).

run({Es, done, M}, _F, _Room, _Answers, Acc, Asked) ->
    {Acc ++ Es, lists:reverse(Asked), M};
run({Es, room, M}, #{entries := Entries} = F, Room, Answers, Acc, Asked) ->
    run(?R:room_checked(Room, Entries, F, M), F, Room, Answers, Acc ++ Es, [room | Asked]);
run({Es, {ask, Nodes, Cont}, M}, F, Room, Answers, Acc, Asked) ->
    run(?R:answered(Answers(Nodes), Cont, F, M), F, Room, Answers, Acc ++ Es,
        [{ask, Nodes} | Asked]).

none_run(Nodes) -> [{ok, []} || _ <- Nodes].

restores(Effects) -> [Id || {restore, Id, _, _} <- Effects].

%% In sync with every peer alive or connected, and a majority heard; in
%% a cluster of two, also alone once `catalogue_alone_ms' has passed since
%% the start; never with a peer whose catalogue it does not have.
ready_test() ->
    F = facts([], []),
    M = mem(100000),
    ?assert(?R:ready(F, M)),
    ?assertNot(?R:ready(F, ?R:new(100000))),
    %% Connected but not yet heard: its catalogue is waited for too.
    ?assertNot(?R:ready(F#{alive := [a@h]}, ?R:new(100000))),
    Alone = F#{alive := [a@h], connected := [], majority := false},
    ?assertNot(?R:ready(Alone, M)),
    ?assertNot(?R:ready(Alone#{now_ms := 129999}, M)),
    ?assert(?R:ready(Alone#{now_ms := 130000}, M)),
    %% Three nodes: alone is never enough.
    ?assertNot(?R:ready(Alone#{size := 3, now_ms := 10000000}, M)),
    %% Not ready: nothing is started, nothing asked.
    ?assertMatch({[], [], _}, run(Alone, M, ok, fun none_run/1)).

%% What this node owns and nobody runs is restored once the connected
%% peers said what they run; not what runs here, there, or belongs to an
%% alive peer; a peer that did not answer may run anything: nothing.
restore_owned_test() ->
    E = [mine(<<"p1">>), mine(<<"p2">>), mine(<<"p3">>),
         {<<"theirs">>, {1, 1, b@h}, {live, cfg(), b@h}}],
    F = facts(E, [{<<"p2">>, pid(2), standby, 1}]),
    There = fun([b@h]) -> [{ok, [{<<"p3">>, pid(3), active, 1}]}] end,
    {Effects, Asked, _} = run(F, mem(0), ok, There),
    ?assertEqual([{ask, [b@h]}], Asked),
    ?assertEqual([{restore, <<"p1">>, cfg(), 1000}], Effects),
    Silent = fun([b@h]) -> [{error, {erpc, timeout}}] end,
    ?assertMatch({[], [{ask, [b@h]}], _}, run(F, mem(0), ok, Silent)),
    %% Nothing to start: nobody is asked.
    ?assertMatch({[], [], _}, run(facts([lists:nth(4, E)], []), mem(0), ok, Silent)),
    %% No connected peer: no question, restored at once; b@h's too, whose
    %% home is gone.
    Lone = F#{alive := [a@h], connected := []},
    {Alone, [], _} = run(Lone, mem(0), ok, Silent),
    ?assertEqual([<<"p1">>, <<"p3">>, <<"theirs">>], restores(Alone)).

%% 1 s, then twice as long each time it is restored again within ten
%% times its wait, up to 5 min; never within its wait; back to 1 s after
%% it lasted ten times its wait.
restore_delay_test() ->
    ?assertEqual(1000, ?R:restore_delay(none, 5)),
    ?assertEqual(wait, ?R:restore_delay({0, 1000}, 999)),
    ?assertEqual(2000, ?R:restore_delay({0, 1000}, 1000)),
    ?assertEqual(2000, ?R:restore_delay({0, 1000}, 9999)),
    ?assertEqual(1000, ?R:restore_delay({0, 1000}, 10000)),
    ?assertEqual(300000, ?R:restore_delay({0, 200000}, 200000)),
    ?assertEqual(300000, ?R:restore_delay({0, 300000}, 300000)),
    ?assertEqual(wait, ?R:restore_delay({0, 300000}, 299999)),
    %% Through the looks: a pairing that keeps dying is restored at 0,
    %% 1000, 3000, 7000 (each wait doubled), not in between.
    F = facts([mine(<<"p">>)], []),
    Times = lists:seq(0, 8000, 250),
    {Restored, _} = lists:foldl(
                      fun(T, {Acc, M}) ->
                              {Es, _, M1} = run(F#{now_ms := T}, M, ok, fun none_run/1),
                              {Acc ++ [{T, Ms} || {restore, _, _, Ms} <- Es], M1}
                      end, {[], mem(-100000)}, Times),
    ?assertEqual([{0, 1000}, {1000, 2000}, {3000, 4000}, {7000, 8000}], Restored).

%% Each local instance of a deleted pairing is asked once to delete
%% itself (said in the log); it is asked again only as another process.
stop_deleted_test() ->
    E = [{<<"gone">>, {2, 1, b@h}, deleted}, mine(<<"kept">>)],
    Roles = [{<<"gone">>, pid(1), standby, 1}, {<<"kept">>, pid(2), standby, 1}],
    F = facts(E, Roles),
    {Es1, _, M1} = run(F, mem(0), ok, fun none_run/1),
    ?assertEqual([{log, notice, #{what => pairing_deleted_elsewhere, pairing => <<"gone">>}},
                  {delete, pid(1)}], Es1),
    ?assertMatch({[], _, _}, run(F, M1, ok, fun none_run/1)),
    %% Gone, then a new instance: that one is asked.
    {_, _, M2} = run(facts(E, []), M1, ok, fun none_run/1),
    ?assertMatch({[_, {delete, _}], _, _}, run(F, M2, ok, fun none_run/1)).

%% A local active (or fenced) instance is monitored once and counts as
%% run here: after it crashed (it gave up), it is not restored here; one
%% that stepped down is restored when no instance is left anywhere.
gave_up_here_test() ->
    E = [mine(<<"p">>)],
    {Es1, _, M1} = run(facts(E, [{<<"p">>, pid(1), fenced, 1}]), mem(0), ok,
                       fun none_run/1),
    ?assertEqual([{monitor, pid(1)}], Es1),
    ?assertMatch({[], _, _}, run(facts(E, [{<<"p">>, pid(1), active, 1}]), M1, ok,
                                 fun none_run/1)),
    {false, Crashed} = ?R:down(pid(1), killed, M1),
    ?assertMatch({[], [{ask, [b@h]}], _}, run(facts(E, []), Crashed, ok, fun none_run/1)),
    {true, Stepped} = ?R:down(pid(1), {shutdown, stale_claim}, M1),
    ?assertMatch({[{restore, <<"p">>, _, _}], _, _},
                 run(facts(E, []), Stepped, ok, fun none_run/1)),
    %% Not watched (any more): nothing to look at.
    ?assertEqual({false, Crashed}, ?R:down(pid(1), normal, Crashed)),
    %% Running elsewhere: it did not give up here.
    Elsewhere = fun(_) -> [{ok, [{<<"p">>, pid(9), active, 2}]}] end,
    {[], _, M2} = run(facts(E, []), Crashed, ok, Elsewhere),
    ?assertMatch({[{restore, <<"p">>, _, _}], _, _}, run(facts(E, []), M2, ok, fun none_run/1)),
    %% A peer that did not answer says nothing of where it runs: it still
    %% gave up here, and is not restored when the peer answers again.
    Silent = fun(_) -> [{error, {erpc, timeout}}] end,
    {[], _, M3} = run(facts(E, []), Crashed, ok, Silent),
    ?assertMatch({[], _, _}, run(facts(E, []), M3, ok, fun none_run/1)),
    %% An ensure of it gives it another chance.
    ?assertMatch({[{restore, <<"p">>, _, _}], _, _},
                 run(facts(E, []), ?R:retry(<<"p">>, Crashed), ok, fun none_run/1)).

%% A pairing started here (created, restored) ran here from its first
%% instant, watched; one gone before it could be looked up is left to
%% the next look.
started_test() ->
    E = [mine(<<"p">>)],
    {[{restore, <<"p">>, _, _}], _, M1} = run(facts(E, []), mem(0), ok, fun none_run/1),
    ?assertEqual({[], M1}, ?R:started(<<"p">>, undefined, M1)),
    {[{monitor, P}], M2} = ?R:started(<<"p">>, pid(5), M1),
    ?assertEqual(pid(5), P),
    %% Watched already: not monitored twice.
    ?assertMatch({[], _}, ?R:started(<<"p">>, pid(5), M2)),
    %% Crashed past its limit before any look saw it: not restored, even
    %% once its back-off is over.
    {false, M3} = ?R:down(pid(5), killed, M2),
    ?assertMatch({[], _, _}, run((facts(E, []))#{now_ms := 10000000}, M3, ok, fun none_run/1)).

%% An ensure that waited for a majority is written once a look is ready
%% and only if the pairing is still absent (a tombstone is written over);
%% kept while the data directory is full; then started as any other.
pending_test() ->
    M0 = ?R:pend(<<"new">>, cfg(), ?R:pend(<<"old">>, cfg(), mem(0))),
    Dead = {<<"new">>, {4, 1, b@h}, deleted},
    Old = {<<"old">>, {1, 1, b@h}, {live, cfg(), b@h}},
    F = facts([Dead, Old], []),
    %% Not ready: not even the room is checked.
    ?assertMatch({[], [], _}, run(F, ?R:pend(<<"new">>, cfg(), ?R:new(0)), ok,
                                  fun none_run/1)),
    {[], [room], M1} = run(F, M0, full, fun none_run/1),
    {Es, Asked, M2} = run(F, M1, ok, fun none_run/1),
    Written = {<<"new">>, {5, 7, a@h}, {live, cfg(), a@h}},
    ?assertEqual([{write, Written}, {log, notice, #{what => pairing_ensured, pairing => <<"new">>}},
                  {restore, <<"new">>, cfg(), 1000}], Es),
    ?assertEqual([room, {ask, [b@h]}], Asked),
    %% Written once: no room asked for again.
    ?assertMatch({[], [{ask, [b@h]}], _}, run(F#{entries := [Written, Old]}, M2, ok,
                                              fun none_run/1)).

%% A peer that becomes alive gets the whole catalogue, every alive peer
%% every `catalogue_sync_ms' or when forced; one that sent its whole
%% catalogue first gets this node's back, once; a peer gone must send its
%% catalogue again before the node is ready.
exchange_test() ->
    Round = fun(T, Alive) -> #{self => a@h, alive => Alive, now_ms => T, sync_ms => 10000} end,
    {[{push, b@h}], M1} = ?R:exchange(Round(100, [a@h, b@h]), false, ?R:new(0)),
    {[], M2} = ?R:exchange(Round(200, [a@h, b@h]), false, M1),
    ?assertMatch({[{push, b@h}], _}, ?R:exchange(Round(200, [a@h, b@h]), true, M2)),
    ?assertMatch({[{push, b@h}], _}, ?R:exchange(Round(10000, [a@h, b@h]), false, M2)),
    {[{push, b@h}], M3} = ?R:exchange(Round(10000, [b@h, a@h]), false, M2),
    {[], _} = ?R:exchange(Round(19999, [a@h, b@h]), false, M3),
    ?assertEqual([{push, b@h}], ?R:sync_now(M3)),
    ?assertEqual([b@h, c@h], ?R:recipients([c@h], M3)),
    %% b@h's whole catalogue: ours goes back once, and a@h is ready.
    F = facts([], []),
    ?assertNot(?R:ready(F, M3)),
    {[], M3} = ?R:received(b@h, false, M3),
    {[{push, b@h}], M4} = ?R:received(b@h, true, M3),
    {[], M4} = ?R:received(b@h, true, M4),
    ?assert(?R:ready(F, M4)),
    %% b@h gone, then back: not ready until it sent its catalogue again.
    {[], M5} = ?R:exchange(Round(20000, [a@h]), false, M4),
    ?assertEqual([], ?R:sync_now(M5)),
    {[{push, b@h}], M6} = ?R:exchange(Round(20100, [a@h, b@h]), false, M5),
    ?assertNot(?R:ready(F, M6)).

%% Over any history of looks (local instances coming and going, peers
%% running pairings or not answering, the disc full or not, ensures,
%% instances crashing or stepping down, time passing), no pairing is
%% restored that runs here or on a peer that answered, or while a peer
%% did not answer, or before the node is ready, or within its back-off;
%% an instance is asked to delete itself once; an ensure is written only
%% when absent and with room.
reconcile_safe_test() ->
    ok = evatar_test_proper:check(prop_reconcile_safe(), 500).

prop_reconcile_safe() ->
    ?FORALL({Entries, Cmds}, {catalogue(), list(command())},
            begin
                {Ok, _} = lists:foldl(fun(Cmd, {true, St}) -> command(Cmd, Entries, St);
                                         (_, Acc) -> Acc
                                      end, {true, {mem(0), 0, #{}, #{}}}, Cmds),
                Ok
            end).

ids() -> oneof([<<"p1">>, <<"p2">>, <<"p3">>]).

command() ->
    frequency([{6, {look, range(0, 3000), few({ids(), oneof([active, standby, fenced])}),
                    oneof([ok, full]), frequency([{3, ok}, {1, silent}]), few(ids()),
                    likely()}},
               %% A round with b@h alive or not; b@h's whole catalogue or
               %% one write from it.
               {1, {exchange, likely()}},
               {1, {received, likely()}},
               {1, {pend, ids()}},
               {1, {started, ids(), boolean()}},
               {2, {down, ids(), oneof([killed, {shutdown, stale_claim}])}}]).

few(T) -> frequency([{2, []}, {2, [T]}, {1, [T, T]}]).

likely() -> frequency([{3, true}, {1, false}]).

%% The state: the rules' memory, the time, the last restore of each id
%% ({At, RetryAfterMs}), the pids asked to delete themselves.
command({exchange, Alive}, _Entries, {M, T, Last, Asked}) ->
    {_, M1} = ?R:exchange(#{self => a@h, alive => [a@h | [b@h || Alive]], now_ms => T,
                            sync_ms => 10000}, false, M),
    {true, {M1, T, Last, Asked}};
command({received, Full}, _Entries, {M, T, Last, Asked}) ->
    {_, M1} = ?R:received(b@h, Full, M),
    {true, {M1, T, Last, Asked}};
command({pend, Id}, _Entries, {M, T, Last, Asked}) ->
    {true, {?R:pend(Id, cfg(), M), T, Last, Asked}};
command({started, Id, Found}, _Entries, {M, T, Last, Asked}) ->
    {_, M1} = ?R:started(Id, case Found of true -> pid(id_n(Id)); false -> undefined end, M),
    {true, {M1, T, Last, Asked}};
command({down, Id, Reason}, _Entries, {M, T, Last, Asked}) ->
    {_, M1} = ?R:down(pid(id_n(Id)), Reason, M),
    {true, {M1, T, Last, Asked}};
command({look, Dt, Local0, Room, Answer, There, Majority}, Entries0,
        {M, T0, Last, Asked}) ->
    T = T0 + Dt,
    Local = maps:to_list(maps:from_list(Local0)),
    Roles = [{Id, pid(id_n(Id)), Role, 1} || {Id, Role} <- Local],
    %% Entries as catalogue() makes them, with homes on a@h or b@h.
    Entries = [{Id, V, case Val of {live, C, _} -> {live, C, N}; D -> D end}
               || {Id, {_, _, N} = V, Val} <- Entries0],
    F = (facts(Entries, Roles))#{now_ms := T, majority := Majority},
    Answers = fun(Nodes) ->
                      case Answer of
                          ok -> [{ok, [{Id, pid(90), active, 1} || Id <- There]} || _ <- Nodes];
                          silent -> [{error, {erpc, timeout}} || _ <- Nodes]
                      end
              end,
    {Es, _, M1} = run(F, M, Room, Answers),
    Restored = restores(Es),
    Deletes = [P || {delete, P} <- Es],
    Written = [Id || {write, {Id, _, _}} <- Es],
    Ready = ?R:ready(F, M),
    Ok = lists:all(fun(Id) ->
                           not lists:keymember(Id, 1, Local)
                               andalso not lists:member(Id, There)
                               andalso Answer =:= ok
                               andalso Ready
                               andalso case Last of
                                           #{Id := {At, Wait}} -> T - At >= Wait;
                                           #{} -> true
                                       end
                   end, Restored)
        andalso lists:all(fun({restore, _, _, W}) -> W >= 1000 andalso W =< 300000;
                             (_) -> true
                          end, Es)
        andalso [P || P <- Deletes, is_map_key(P, Asked)] =:= []
        andalso (Written =:= [] orelse (Room =:= ok andalso Ready))
        andalso [Id || Id <- Written, {I, _, {live, _, _}} <- Entries, I =:= Id] =:= [],
    Last1 = maps:merge(Last, maps:from_list([{Id, {T, W}} || {restore, Id, _, W} <- Es])),
    %% A pid gone from the roles may be asked again when it comes back
    %% (a new instance would have another pid).
    Asked1 = maps:merge(maps:with([P || {_, P, _, _} <- Roles], Asked),
                        maps:from_list([{P, true} || P <- Deletes])),
    {Ok, {M1, T, Last1, Asked1}}.

id_n(<<"p", N/binary>>) -> binary_to_integer(N).
