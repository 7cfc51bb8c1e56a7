%% -*- erlang -*-
%% A test node driven by commands on stdin, for the tests of clients in other
%% languages (clients/python, clients/java) that need more than
%% scripts/test-node.sh: port connectors and avatar_sim's smart home on a
%% simulated clock. Run it through scripts/test-node-ctl.sh (which sets the
%% code path). It listens on 127.0.0.1 (EVATAR_PORT or a free port),
%% creates the pairings named on the command line, prints
%%   EVATAR_PORT=<port>
%% and then answers each command line with one or more lines, the last
%% starting with OK or ERROR. It halts when stdin closes.
%%
%% Arguments: PAIRING:AGENT_CREDENTIAL:AVATAR_CREDENTIAL[:FEEDBACK_TIMEOUT_MS]...
%%            [--home PAIRING:AVATAR_CREDENTIAL:SPOOL_DIR] [--cluster N]
%% --cluster N starts instead N EVATAR nodes in a cluster (separate OS
%% processes, peer nodes on 127.0.0.1), each with a listener; the pairings
%% are created on node 1 (active) with their standby on node 2, and the
%% script waits until the standby is synced. It prints
%%   EVATAR_PORTS=<port1>,<port2>,...
%% before EVATAR_PORT=<port1>.
%% --home starts the easy smart home (one gateway with every device) joined
%% to PAIRING, on a clock at 17:55 on 2024-11-15 running at speed 2, with the
%% holiday evening's script (an intruder at 21:40), as
%% reference_agents_holiday does; --home-start YYYY-MM-DDTHH:MM starts the
%% clock at another date and time.
%%
%% Commands:
%%   port NAME PROGRAM [ARG...]   start PROGRAM under a port connector
%%   stop_port NAME
%%   runs NAME                    how many times the port's program started
%%   entities PAIRING             the EntityIDs registered in the pairing
%%   speed N                      pause the home's clock and set its speed
%%   run_until HH:MM              run the clock until that local time, pause
%%   outcome                      the home's state: LIGHT/EMAIL/PHOTO/PLAYED lines
%%   kill I                       (cluster) kill -9 node I (1-based)
%%   freeze I                     (cluster) kill -STOP node I: a node that hangs
%%   ha PAIRING                   (cluster) HA I ROLE EPOCH per node holding the pairing
-mode(compile).

main(Args0) ->
    %% Stdout carries the command protocol (lines up to OK or ERROR); log
    %% reports, such as a killed peer's, go to stderr so a reader never
    %% takes them for answers.
    ok = logger:remove_handler(default),
    ok = logger:add_handler(default, logger_std_h, #{config => #{type => standard_error}}),
    case lists:splitwith(fun(A) -> A =/= "--cluster" end, Args0) of
        {Args, ["--cluster", N | More]} -> cluster(list_to_integer(N), Args ++ More);
        {Args, []} -> single(Args)
    end.

single(Args0) ->
    {Args, Start} = case lists:splitwith(fun(A) -> A =/= "--home-start" end, Args0) of
                        {Before, ["--home-start", When | After]} ->
                            {Before ++ After, datetime(When)};
                        {_, []} ->
                            {Args0, reference_agents_holiday:start_datetime()}
                    end,
    put(home_start, Start),
    {Pairings, Home} = args(Args, [], none),
    %% EVATAR_LOG_LEVEL=notice shows what port programs write on stderr.
    Level = list_to_existing_atom(os:getenv("EVATAR_LOG_LEVEL", "warning")),
    logger:set_primary_config(level, Level),
    application:load(agent_bridge),
    application:set_env(agent_bridge, listeners, []),
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    [{ok, _} = evatar:create_pairing(Id, Opts) || {Id, Opts} <- Pairings],
    Port = case os:getenv("EVATAR_PORT") of false -> 0; P -> list_to_integer(P) end,
    %% Heartbeat 500: the value in the shared vectors' Welcome, which the
    %% SDKs' transcript tests replay against this node.
    {ok, _} = agent_bridge:start_listener(test_node, #{ip => {127, 0, 0, 1}, port => Port,
                                                       conn => #{heartbeat => 500}}),
    {ok, {_, Bound}} = agent_bridge:address(test_node),
    State = start_home(Home, Bound),
    io:format("EVATAR_PORT=~b~n", [Bound]),
    loop(State).

args([], Acc, Home) -> {lists:reverse(Acc), Home};
args(["--home", Spec | Rest], Acc, _) ->
    [Pairing, Cred | SpoolParts] = string:split(Spec, ":", all),
    args(Rest, Acc, {list_to_binary(Pairing), list_to_binary(Cred), lists:join(":", SpoolParts)});
args([Spec | Rest], Acc, Home) ->
    Opts = case string:split(Spec, ":", all) of
               [Id, A, V] when Id =/= "", A =/= "", V =/= "" ->
                   {Id, #{agent_credential => list_to_binary(A),
                          avatar_credential => list_to_binary(V)}};
               [Id, A, V, T] when Id =/= "", A =/= "", V =/= "" ->
                   {Id, #{agent_credential => list_to_binary(A),
                          avatar_credential => list_to_binary(V),
                          feedback_timeout => list_to_integer(T)}};
               _ ->
                   io:format(standard_error, "bad pairing ~s~n", [Spec]),
                   halt(2)
           end,
    {Id1, O} = Opts,
    args(Rest, [{list_to_binary(Id1), O} | Acc], Home).

start_home(none, _Port) ->
    #{};
start_home({Pairing, Cred, Spool}, Port) ->
    {ok, _} = application:ensure_all_started(avatar_sim),
    {ok, Clock} = avatar_sim:start_clock(#{speed => 2, tick => 500,
                                           start => get(home_start)}),
    {ok, Home} = avatar_sim:start_home(#{clock => Clock, seed => 1,
                                         endpoints => [{{127, 0, 0, 1}, Port}],
                                         spool => Spool,
                                         script => reference_agents_holiday:default_script(),
                                         gateways => [#{pairing => Pairing,
                                                        credential => Cred}]}),
    #{clock => Clock, home => Home}.

loop(S) ->
    case io:get_line('') of
        eof -> stop();
        {error, _} -> stop();
        Line ->
            Words = string:lexemes(string:trim(Line), " "),
            try command(Words, S) of
                S1 -> loop(S1)
            catch C:R ->
                    io:format("ERROR ~0p~n", [{C, R}]),
                    loop(S)
            end
    end.

command(["port", Name, Program | Args], S) ->
    {ok, _} = agent_bridge:start_port(list_to_binary(Name),
                                      #{command => Program, args => Args,
                                        backoff_min => 100, backoff_max => 2000}),
    ok(S);
command(["stop_port", Name], S) ->
    ok = agent_bridge:stop_port(list_to_binary(Name)),
    ok(S);
command(["runs", Name], S) ->
    [Pid] = [P || {{agent_bridge_port, N}, P, _, _} <- supervisor:which_children(agent_bridge_port_sup),
                  N =:= list_to_binary(Name)],
    io:format("RUNS ~b~n", [agent_bridge_port:runs(Pid)]),
    ok(S);
command(["entities", Pairing], S) ->
    {ok, Registry} = evatar:registry(list_to_binary(Pairing)),
    io:format("ENTITIES ~s~n", [lists:join(" ", [Id || #{entity := Id} <- Registry])]),
    ok(S);
command(["speed", N], #{clock := Clock} = S) ->
    ok = avatar_sim:pause(Clock),
    ok = avatar_sim:set_speed(Clock, list_to_integer(N)),
    ok(S);
command(["run_until", HHMM], #{clock := Clock} = S) ->
    Target = target_ms(avatar_sim:now(Clock), HHMM),
    ok = avatar_sim:resume(Clock),
    wait_clock(Clock, Target),
    ok = avatar_sim:pause(Clock),
    ok(S);
command(["outcome"], #{home := Home} = S) ->
    #{light_log := Log, emails := Emails, photos := Photos, played := Played} =
        avatar_sim:state(Home),
    [io:format("LIGHT ~s ~s ~s~n", [hhmm(T), R, St]) || #{time := T, room := R, state := St} <- Log],
    [io:format("EMAIL ~s\t~s\t~s~n", [F, Sub, lists:join(",", A)])
     || #{file := F, subject := Sub, attachments := A} <- Emails],
    [io:format("PHOTO ~s\t~s\t~s~n", [I, R, F]) || #{id := I, room := R, file := F} <- Photos],
    [io:format("PLAYED ~s\t~b\t~s~n", [K, V, W])
     || #{kind := K, volume := V, what := W} <- Played],
    ok(S);
command(["kill", I], #{ospids := OsPids} = S) ->
    _ = os:cmd("kill -9 " ++ lists:nth(list_to_integer(I), OsPids)),
    ok(S);
command(["freeze", I], #{ospids := OsPids} = S) ->
    OsPid = lists:nth(list_to_integer(I), OsPids),
    _ = os:cmd("kill -STOP " ++ OsPid),
    %% kill -9 when this script ends: a stopped node would not see its
    %% control connection close.
    put(frozen, [OsPid | case get(frozen) of undefined -> []; F -> F end]),
    ok(S);
command(["ha", Pairing], #{nodes := Nodes} = S) ->
    Id = list_to_binary(Pairing),
    [case catch peer:call(P, evatar, ha_status, [Id], 2000) of
         {ok, #{role := Role, epoch := Epoch}} -> io:format("HA ~b ~s ~b~n", [I, Role, Epoch]);
         _ -> ok
     end || {I, {P, _}} <- lists:zip(lists:seq(1, length(Nodes)), Nodes)],
    ok(S);
command(Other, S) ->
    io:format("ERROR unknown command ~0p~n", [Other]),
    S.

ok(S) -> io:format("OK~n"), S.

stop() ->
    _ = [os:cmd("kill -9 " ++ OsPid) || OsPid <- case get(frozen) of
                                                     undefined -> [];
                                                     F -> F
                                                 end],
    halt(0).

%% A cluster of N peer nodes, set up as apps/evatar/test/evatar_ha_SUITE does.
cluster(N, Args) ->
    {Pairings, none} = args(Args, [], none),
    Unique = os:getpid(),
    Names = [list_to_atom("evatar_ctl" ++ integer_to_list(I) ++ "_" ++ Unique)
             || I <- lists:seq(1, N)],
    NodeNames = [list_to_atom(atom_to_list(Nm) ++ "@127.0.0.1") || Nm <- Names],
    %% A random cookie, and distribution on loopback only: no one else can
    %% run code on these nodes.
    Cookie = lists:flatten([io_lib:format("~2.16.0b", [B]) || <<B>> <= crypto:strong_rand_bytes(24)]),
    Started = [begin
                   {ok, P, Node} = peer:start(#{name => Nm, host => "127.0.0.1",
                                                longnames => true, connection => standard_io,
                                                args => ["-setcookie", Cookie,
                                                         "-kernel", "inet_dist_use_interface",
                                                         "{127,0,0,1}",
                                                         "-kernel", "prevent_overlapping_partitions",
                                                         "false"]}),
                   {P, Node}
               end || Nm <- Names],
    Ports = [setup_peer(P, NodeNames) || {P, _} <- Started],
    wait(fun() -> lists:all(fun({P, _}) ->
                                    length(maps:get(up, peer:call(P, evatar, cluster_status, [])))
                                        =:= N
                            end, Started)
         end),
    [{P1, _}, {_, Node2} | _] = Started,
    [{ok, _} = peer:call(P1, evatar, create_pairing, [Id, O#{standby_node => Node2}])
     || {Id, O} <- Pairings],
    wait(fun() -> lists:all(fun({Id, _}) ->
                                    case peer:call(P1, evatar, ha_status, [Id]) of
                                        {ok, #{role := active, synced := true}} -> true;
                                        _ -> false
                                    end
                            end, Pairings)
         end),
    io:format("EVATAR_PORTS=~s~n", [lists:join(",", [integer_to_list(Pt) || Pt <- Ports])]),
    io:format("EVATAR_PORT=~b~n", [hd(Ports)]),
    OsPids = [peer:call(P, os, getpid, []) || {P, _} <- Started],
    loop(#{nodes => Started, ospids => OsPids}).

setup_peer(P, Nodes) ->
    ok = peer:call(P, application, load, [evatar]),
    ok = peer:call(P, application, load, [agent_bridge]),
    ok = peer:call(P, logger, set_primary_config, [level, error]),
    Env = [{cluster, Nodes}, {heartbeat_ms, 100}, {suspect_ms, 1000}, {lease_ms, 600},
           {resume_timeout, 10000}],
    _ = [ok = peer:call(P, application, set_env, [evatar, K, V]) || {K, V} <- Env],
    ok = peer:call(P, application, set_env, [agent_bridge, listeners, []]),
    {ok, _} = peer:call(P, application, ensure_all_started, [agent_bridge]),
    %% Slow timings, as above, for a loaded machine: heartbeat 500.
    {ok, _} = peer:call(P, agent_bridge, start_listener,
                        [ctl, #{ip => {127, 0, 0, 1}, port => 0,
                                conn => #{heartbeat => 500}}]),
    {ok, {_, Port}} = peer:call(P, agent_bridge, address, [ctl]),
    Port.

wait(F) -> wait(F, 200).
wait(_F, 0) -> error(timeout);
wait(F, N) ->
    case F() of
        true -> ok;
        false -> timer:sleep(50), wait(F, N - 1)
    end.

wait_clock(Clock, Target) ->
    case avatar_sim:now(Clock) >= Target of
        true -> ok;
        false -> timer:sleep(20), wait_clock(Clock, Target)
    end.

datetime(Text) ->
    [Date, Time] = string:split(Text, "T"),
    [Y, Mo, D] = [list_to_integer(X) || X <- string:split(Date, "-", all)],
    [H, Mi] = [list_to_integer(X) || X <- string:split(Time, ":", all)],
    {{Y, Mo, D}, {H, Mi, 0}}.

hhmm(Ms) ->
    {_, {H, M, _}} = calendar:system_time_to_universal_time(Ms, millisecond),
    io_lib:format("~2..0b:~2..0b", [H, M]).

target_ms(NowMs, HHMM) ->
    [H, M] = [list_to_integer(X) || X <- string:split(HHMM, ":")],
    {Date, _} = calendar:system_time_to_universal_time(NowMs, millisecond),
    Day = (calendar:datetime_to_gregorian_seconds({Date, {0, 0, 0}})
           - calendar:datetime_to_gregorian_seconds({{1970, 1, 1}, {0, 0, 0}})) * 1000,
    T = Day + (H * 60 + M) * 60000,
    case T > NowMs of
        true -> T;
        false -> T + 86400000
    end.
