%% @doc Internal. The embodiment test of Fig. 8, pure: once EVATAR reports
%% a binding, the VA tests every relationship of its body. An actuator or
%% behaviour is tested by a request that must come back with feedback; a
%% sensor by the sensory input it must deliver (the answer to a read
%% request, or a reading pushed to the emulator). The outcome records that
%% the VA is embodied, or exactly which relationship failed and why.
-module(reference_agents_embodiment).

-export([start/2, result/3, reading/2, done/1, pending/1, report/1, format/1]).

-export_type([test/0, probe/0, step/0, report/0, check/0]).

%% What the VA's mind says about one bound consumer entry: test it with a
%% request carrying these values, or do not test it by request (a sensor
%% emulator with no read request is then tested by waiting for a reading).
-type probe() :: {request, [{binary(), binary()}]} | skip.
-type check() :: #{id := pos_integer(), emulator := binary(), kind := atom(),
                   how := request | reading, service := binary(),
                   provider := binary()}.
%% What the VA must do to run the test.
-type step() :: {request, Id :: pos_integer(), Emulator :: binary(), Service :: binary(),
                 [{binary(), binary()}]}
              | {await_reading, Id :: pos_integer(), Emulator :: binary()}.
-type outcome() :: ok | {failed, binary()}.
-type report() :: #{verdict := embodied | partial | none,
                    passed := [check()],
                    untested := [#{emulator := binary(), service := binary(),
                                   provider := binary()}],
                    failed := [{check() | #{emulator := binary(), service := binary()},
                                binary()}]}.

-record(test, {checks = [] :: [check()],
               untested = [] :: [#{emulator := binary(), service := binary(),
                                   provider := binary()}],
               results = #{} :: #{pos_integer() => outcome()},
               unbound = [] :: [{#{emulator := binary(), service := binary()}, binary()}]}).
-opaque test() :: #test{}.

%% @doc Plans the test for the VA's current binding. `Probe' is asked for
%% each bound consumer entry; every sensor emulator fed by the Avatar and
%% not tested by a request is tested by a reading. Entries EVATAR could not
%% bind fail at once.
-spec start(reference_agents_emulator:table(), fun((reference_agents_emulator:link()) -> probe())) ->
          {test(), [step()]}.
start(Table, Probe) ->
    Probes = [{L, Probe(L)} || L <- reference_agents_emulator:bound(Table)],
    Requests = [{L, P} || {L, {request, P}} <- Probes],
    {Checks1, Steps1, N1} =
        lists:foldl(
          fun({#{emulator := E, type := Ty, provider := Pr}, Params}, {Cs, Ss, N}) ->
                  C = #{id => N, emulator => E, kind => reference_agents_emulator:kind(E, Table),
                        how => request, service => Ty, provider => Pr},
                  {[C | Cs], [{request, N, E, Ty, Params} | Ss], N + 1}
          end, {[], [], 1}, Requests),
    Requested = [E || #{emulator := E} <- Checks1],
    Sensors = [E || E <- reference_agents_emulator:emulators(Table),
                    reference_agents_emulator:kind(E, Table) =:= sensor,
                    reference_agents_emulator:sources(E, Table) =/= [],
                    not lists:member(E, Requested)],
    {Checks2, Steps2, _} =
        lists:foldl(
          fun(E, {Cs, Ss, N}) ->
                  [Source | _] = reference_agents_emulator:sources(E, Table),
                  C = #{id => N, emulator => E, kind => sensor, how => reading,
                        service => <<"reading">>, provider => Source},
                  {[C | Cs], [{await_reading, N, E} | Ss], N + 1}
          end, {Checks1, Steps1, N1}, Sensors),
    Unbound = [{#{emulator => E, service => <<Cat/binary, "/", Ty/binary>>},
                iolist_to_binary(["not bound by EVATAR (", atom_to_binary(R), ")"])}
               || #{emulator := E, category := Cat, type := Ty, reason := R}
                      <- reference_agents_emulator:unbound(Table)],
    Tested = [E || #{emulator := E} <- Checks2],
    Untested = [#{emulator => E, service => Ty, provider => Pr}
                || {#{emulator := E, type := Ty, provider := Pr}, skip} <- Probes,
                   not lists:member(E, Tested)],
    {#test{checks = lists:reverse(Checks2), unbound = Unbound, untested = Untested},
     lists:reverse(Steps2)}.

%% @doc Records the outcome of one check; a check already decided keeps its
%% first outcome.
-spec result(pos_integer(), outcome(), test()) -> test().
result(Id, Outcome, #test{results = R} = T) ->
    case maps:is_key(Id, R) of
        true -> T;
        false -> T#test{results = R#{Id => Outcome}}
    end.

%% @doc A reading reached `Emulator': its reading check passes.
-spec reading(binary(), test()) -> test().
reading(Emulator, #test{checks = Cs} = T) ->
    lists:foldl(fun(#{id := Id, emulator := E, how := reading}, Acc) when E =:= Emulator ->
                        result(Id, ok, Acc);
                   (_, Acc) -> Acc
                end, T, Cs).

%% @doc True when every check has an outcome.
-spec done(test()) -> boolean().
done(T) -> pending(T) =:= [].

%% @doc The checks without an outcome yet.
-spec pending(test()) -> [check()].
pending(#test{checks = Cs, results = R}) ->
    [C || #{id := Id} = C <- Cs, not maps:is_key(Id, R)].

%% @doc The verdict: embodied when every relationship works, partial when
%% some do, none when none does. Checks still pending count as failed
%% ("no answer").
-spec report(test()) -> report().
report(#test{checks = Cs, results = R, unbound = U, untested = Untested}) ->
    Passed = [C || #{id := Id} = C <- Cs, maps:get(Id, R, undefined) =:= ok],
    Failed = [{C, case maps:get(Id, R, undefined) of
                      {failed, Why} -> Why;
                      undefined -> <<"no answer before the test ended">>
                  end} || #{id := Id} = C <- Cs, maps:get(Id, R, undefined) =/= ok] ++ U,
    Verdict = case {Passed, Failed} of
                  {[_ | _], []} -> embodied;
                  {[_ | _], _} -> partial;
                  {[], _} -> none
              end,
    #{verdict => Verdict, passed => Passed, failed => Failed, untested => Untested}.

%% @doc The report as lines a person reads.
-spec format(report()) -> [iodata()].
format(#{verdict := V, passed := P, failed := F, untested := U}) ->
    [io_lib:format("embodiment test: ~s (~b relationship(s) work, ~b failed, ~b not tested)",
                   [V, length(P), length(F), length(U)])
     | [io_lib:format("  FAILED ~s ~s~s: ~s",
                      [E, S, case C of #{provider := Pr} -> [" -> ", Pr]; _ -> "" end, Why])
        || {#{emulator := E, service := S} = C, Why} <- F]]
        ++ [io_lib:format("  not tested: ~s ~s -> ~s (a test would have effects)", [E, S, Pr])
            || #{emulator := E, service := S, provider := Pr} <- U].
