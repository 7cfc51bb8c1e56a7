%% @doc The rolling upgrade and the replacement of a dead machine, on real
%% release nodes (docs/ha.md section 8), run by `make test-upgrade'
%% (scripts/test-upgrade.sh). Three nodes of the old release, started
%% with scripts/cluster.sh, carry six pairings (two created on each) with
%% a VA and an Avatar each, exchanging requests and feedback through the
%% bridges; each node in turn is stopped (`bin/evatar stop') and started
%% again from the new release on the same data directory, and the run
%% waits until every pairing has one active and one synced standby again.
%% Then node 3 is killed (kill -9), its data directory removed (a new
%% machine under the old name) and started empty; it must get the whole
%% catalogue and hold instances again. At the end the traffic stops, every
%% signal must have arrived exactly once (evatar_test_checker), and every
%% node's catalogue must list the six pairings. Prints one line per step
%% and the checker's counts; fails (status 1) on anything else.
-module(upgrade_bench).

-export([main/1]).

-define(N, 3).
-define(PAIRINGS, 6).
-define(WAIT, 120000).

%% @doc Opts: `{old, Rel}', `{new, Rel}' (release directories), `{dir,
%% Dir}' (the cluster's directory, emptied first).
-spec main([{atom(), string()}]) -> ok.
main(Opts) ->
    Old = proplists:get_value(old, Opts),
    New = proplists:get_value(new, Opts),
    Dir = proplists:get_value(dir, Opts),
    _ = os:cmd("rm -rf " ++ Dir),
    ok = filelib:ensure_path(filename:join(Dir, "home")),
    Base = 17600 + rand:uniform(200) * 3,
    Ctx = #{dir => Dir, old => Old, new => New, base => Base},
    try run(Ctx)
    after
        _ = cluster(Ctx, New, "stop " ++ integer_to_list(?N)),
        _ = cluster(Ctx, Old, "stop " ++ integer_to_list(?N))
    end.

run(Ctx) ->
    T0 = erlang:monotonic_time(millisecond),
    say(T0, "starting ~b nodes of the old release ~s", [?N, maps:get(old, Ctx)]),
    _ = cluster(Ctx, maps:get(old, Ctx), "start " ++ integer_to_list(?N)),
    ok = connect(Ctx),
    ok = await(fun() -> length(up(Ctx)) =:= ?N end, formed),
    Ids = [list_to_binary("upg-" ++ integer_to_list(K)) || K <- lists:seq(1, ?PAIRINGS)],
    _ = [{ok, _} = erpc:call(node_name(1 + (K - 1) rem ?N), evatar, create_pairing,
                             [Id, evatar_test_traffic:pairing_opts()])
         || {K, Id} <- lists:zip(lists:seq(1, ?PAIRINGS), Ids)],
    Endpoints = [{{127, 0, 0, 1}, maps:get(base, Ctx) + I} || I <- lists:seq(1, ?N)],
    Pairs = [begin
                 {ok, P} = evatar_test_traffic:start_pair(Endpoints, Id, #{request_interval => 20}),
                 P
             end || Id <- Ids],
    ok = await(fun() -> healthy(Ids) end, healthy),
    say(T0, "~b pairings with traffic, each with an active and a synced standby", [?PAIRINGS]),
    lists:foreach(fun(I) ->
                          {0, _} = node_cmd(Ctx, maps:get(old, Ctx), I, "stop"),
                          say(T0, "node ~b stopped (old release)", [I]),
                          ok = await(fun() -> served(Ids, I) end, {served_without, I}),
                          _ = cluster(Ctx, maps:get(new, Ctx), "start " ++ integer_to_list(?N)),
                          ok = connect(Ctx),
                          ok = await(fun() -> length(up(Ctx)) =:= ?N end, {rejoined, I}),
                          ok = await(fun() -> healthy(Ids) end, {healthy_after, I}),
                          say(T0, "node ~b runs the new release; every pairing healthy", [I])
                  end, lists:seq(1, ?N)),
    %% A dead machine replaced by a new one under the same name.
    {0, _} = node_cmd(Ctx, maps:get(new, Ctx), 3, "pid"),
    _ = cluster(Ctx, maps:get(new, Ctx), "kill 3"),
    _ = os:cmd("rm -rf " ++ filename:join([maps:get(dir, Ctx), "upg3", "data"])),
    say(T0, "node 3 killed, its data directory removed", []),
    ok = await(fun() -> served(Ids, 3) end, served_without_3),
    _ = cluster(Ctx, maps:get(new, Ctx), "start " ++ integer_to_list(?N)),
    ok = connect(Ctx),
    ok = await(fun() -> length(up(Ctx)) =:= ?N end, replaced),
    ok = await(fun() -> length(live(3)) =:= ?PAIRINGS end, catalogue_on_3),
    ok = await(fun() -> healthy(Ids) andalso instances_on(3, Ids) > 0 end, share_on_3),
    say(T0, "new node 3 has the catalogue (~b pairings) and holds ~b instances",
        [length(live(3)), instances_on(3, Ids)]),
    _ = [ok = evatar_test_traffic:stop_traffic(P) || P <- Pairs],
    _ = [ok = evatar_test_traffic:settle(P, ?WAIT) || P <- Pairs],
    Result = evatar_test_checker:check_pairs([evatar_test_traffic:history(P) || P <- Pairs]),
    _ = [evatar_test_traffic:close(P) || P <- Pairs],
    Catalogues = [length(live(I)) || I <- lists:seq(1, ?N)],
    say(T0, "signals: ~s; catalogue sizes ~w", [evatar_test_checker:format(Result), Catalogues]),
    true = evatar_test_checker:passed(Result),
    [?PAIRINGS, ?PAIRINGS, ?PAIRINGS] = Catalogues,
    say(T0, "rolling upgrade and replacement: passed", []),
    ok.

%% ---------------------------------------------------------------------------

cluster(#{dir := Dir, base := Base}, Rel, Args) ->
    Cmd = lists:flatten(["HOME=", Dir, "/home EVATAR_REL=", Rel, " EVATAR_CLUSTER_DIR=", Dir,
                         " EVATAR_NAME=upg EVATAR_BASE_PORT=", integer_to_list(Base),
                         " EVATAR_DIST_BASE=", integer_to_list(Base + 1000),
                         " EVATAR_HTTP_BASE=", integer_to_list(Base + 20),
                         " scripts/cluster.sh ", Args, " 2>&1"]),
    os:cmd(Cmd).

%% bin/evatar of release Rel with node I's environment.
node_cmd(#{dir := Dir, base := Base} = Ctx, Rel, I, Command) ->
    Env = cluster(Ctx, Rel, "env " ++ integer_to_list(I) ++ " " ++ integer_to_list(?N)),
    Out = os:cmd(lists:flatten(["HOME=", Dir, "/home; export HOME; ", Env, "\n",
                                Rel, "/bin/evatar ", Command, " 2>&1; echo rc=$?"])),
    _ = Base,
    [Last | _] = lists:reverse(string:lexemes(Out, "\n")),
    "rc=" ++ Rc = Last,
    {list_to_integer(Rc), Out}.

connect(#{dir := Dir}) ->
    case node() of
        nonode@nohost ->
            {ok, _} = net_kernel:start('upgctl@127.0.0.1', #{name_domain => longnames,
                                                             hidden => true}),
            ok;
        _ ->
            ok
    end,
    {ok, Cookie} = file:read_file(filename:join([Dir, "home", ".erlang.cookie"])),
    true = erlang:set_cookie(binary_to_atom(string:trim(Cookie))),
    ok.

node_name(I) -> list_to_atom("upg" ++ integer_to_list(I) ++ "@127.0.0.1").

up(_Ctx) ->
    [I || I <- lists:seq(1, ?N), net_adm:ping(node_name(I)) =:= pong,
          is_list(catch erpc:call(node_name(I), evatar_cluster, alive_nodes, [], 2000))].

%% Every pairing has exactly one active and one synced standby, as seen
%% from every node up.
healthy(Ids) ->
    Up = up(x),
    Up =/= [] andalso
        lists:all(fun(Id) ->
                          Roles = locate(hd(Up), Id),
                          lists:sort([R || {_, #{role := R}} <- Roles]) =:= [active, standby]
                              andalso lists:all(fun({_, #{role := standby, synced := S}}) -> S;
                                                   (_) -> true
                                                end, Roles)
                  end, Ids).

%% Every pairing active on a node other than I.
served(Ids, I) ->
    Others = [J || J <- up(x), J =/= I],
    Others =/= [] andalso
        lists:all(fun(Id) ->
                          [N || {N, #{role := active}} <- locate(hd(Others), Id),
                                N =/= node_name(I)] =/= []
                  end, Ids).

locate(I, Id) ->
    case catch erpc:call(node_name(I), evatar, ha_locate, [Id], 5000) of
        L when is_list(L) -> L;
        _ -> []
    end.

instances_on(I, Ids) ->
    length([x || Id <- Ids, {N, _} <- locate(I, Id), N =:= node_name(I)]).

live(I) ->
    case catch erpc:call(node_name(I), evatar_catalogue, entries, [], 5000) of
        L when is_list(L) -> [Id || {Id, _, {live, _, _}} <- L];
        _ -> []
    end.

await(Fun, What) ->
    case evatar_test_wait:poll(Fun, #{timeout => ?WAIT, interval => 200, what => What}) of
        ok -> ok;
        {error, _} = Error -> erlang:error(Error)
    end.

say(T0, Fmt, Args) ->
    io:format("upgrade ~6.1f s: " ++ Fmt ++ "~n",
              [(erlang:monotonic_time(millisecond) - T0) / 1000 | Args]).
