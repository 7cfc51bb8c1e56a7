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
%%            [--home PAIRING:AVATAR_CREDENTIAL:SPOOL_DIR] [--script holiday|none|FILE]
%%            [--robots PAIRING1:CREDENTIAL1,PAIRING2:CREDENTIAL2] [--speed N]
%%            [--home-start YYYY-MM-DDTHH:MM] [--paused] [--control SOCKET] [--no-stdin]
%%            [--cluster N]
%% --cluster N starts instead N EVATAR nodes in a cluster (separate OS
%% processes, peer nodes on 127.0.0.1), each with a listener; the pairings
%% are created on node 1 (active) with their standby on node 2, and the
%% script waits until the standby is synced. It prints
%%   EVATAR_PORTS=<port1>,<port2>,...
%% before EVATAR_PORT=<port1>. With --home or --robots the simulated Avatar
%% runs in this script's own VM, given every node's endpoint.
%% --home starts the easy smart home (one gateway with every device) joined
%% to PAIRING, on a clock at 17:55 on 2024-11-15 running at speed 2, with the
%% holiday evening's script (an intruder at 21:40), as
%% evatar_demo_holiday does; --home-start YYYY-MM-DDTHH:MM starts the
%% clock at another date and time. --script chooses the people's script:
%% holiday (the default), none, or a script file (docs/avatars.md section
%% 4.3). --robots starts instead the LEGO arena with two robots, each
%% joined to its pairing. --speed sets the clock's speed (default 2).
%% --paused starts the clock paused: simulated time stands still until the
%% `resume' (or `run_until') command, so a VA can join and bind first.
%% --control SOCKET also takes commands, one per connection, on a Unix
%% domain socket at that path (make its directory private: anyone who can
%% open the socket can drive the simulation); --no-stdin stops reading
%% stdin, so the node runs until the `stop' command. Answers go back on the
%% connection that asked. scripts/sim-node.sh wraps both for users;
%% `test-node-ctl.sh --send SOCKET COMMAND...' is its client
%% (scripts/test-node-ctl-send.escript): it prints the answer's lines and
%% exits 0 on OK, 1 on ERROR (printed to stderr), 3 when nothing answers on
%% SOCKET. When the answer has no lines it prints a short confirmation
%% instead (`ok muted LivingLightSwitch01'; `outcome' with nothing to show
%% says so), so every command prints something.
%%
%% Commands:
%%   port NAME PROGRAM [ARG...]   start PROGRAM under a port connector
%%   stop_port NAME
%%   runs NAME                    how many times the port's program started
%%   entities PAIRING             the EntityIDs registered in the pairing
%%   speed N                      pause the home's clock and set its speed
%%   run_until HH:MM              run the clock until that local time, pause
%%   time                         TIME YYYY-MM-DD HH:MM:SS running|paused speed=N
%%                                (the simulated time, UTC = the home's local time)
%%   outcome                      the home's state: LIGHT/EMAIL/PHOTO/PLAYED lines;
%%                                the arena's: BALL COLOUR X Y ZONE|none HELD_BY|none
%%                                and ROBOT ENTITY X Y HOLDING|none lines
%%   kill I                       (cluster) kill -9 node I (1-based)
%%   freeze I                     (cluster) kill -STOP node I: a node that hangs
%%   ha PAIRING                   (cluster) HA I ROLE EPOCH per node holding the pairing
%%   mute COMPONENT, unmute COMPONENT, disconnect ENTITY [MS], reconnect ENTITY,
%%   detach COMPONENT, attach COMPONENT
%%                                the failure hooks of docs/avatars.md section 5
%%   links                        LINK ENTITY PAIRING STATE routes=N muted=C,.. detached=C,..
%%   pause, resume                stop and restart the simulated clock
%%   stop                         answers OK, then halts the node
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

single(Args) ->
    {Opts, Specs} = options(Args, #{}, []),
    Pairings = [pairing(Spec) || Spec <- Specs],
    %% EVATAR_LOG_LEVEL=notice shows what port programs write on stderr.
    Level = list_to_existing_atom(os:getenv("EVATAR_LOG_LEVEL", "warning")),
    logger:set_primary_config(level, Level),
    application:load(agent_bridge),
    application:set_env(agent_bridge, listeners, []),
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    [{ok, _} = evatar:create_pairing(Id, O) || {Id, O} <- Pairings],
    Port = case os:getenv("EVATAR_PORT") of false -> 0; P -> list_to_integer(P) end,
    %% Heartbeat 500: the value in the shared vectors' Welcome, which the
    %% SDKs' transcript tests replay against this node.
    case agent_bridge:start_listener(test_node, #{ip => {127, 0, 0, 1}, port => Port,
                                                  conn => #{heartbeat => 500}}) of
        {ok, _} ->
            ok;
        {error, Why} ->
            Text = lists:flatten(io_lib:format("~0p", [Why])),
            Reason = case string:find(Text, "eaddrinuse") of
                         nomatch -> Text;
                         _ -> "the port is in use (port 0 picks a free one)"
                     end,
            io:format(standard_error, "cannot listen on 127.0.0.1:~b: ~s~n", [Port, Reason]),
            halt(2)
    end,
    {ok, {_, Bound}} = agent_bridge:address(test_node),
    State = start_sim(Opts, [{{127, 0, 0, 1}, Bound}]),
    Main = self(),
    _ = [spawn_link(fun() -> control(Path, Main) end) || #{control := Path} <- [Opts]],
    _ = [receive {control, listening, Path} -> put(control, Path) after 5000 -> error(no_control) end
         || #{control := Path} <- [Opts]],
    _ = [spawn_link(fun() -> read_stdin(Main) end) || maps:get(stdin, Opts, true)],
    io:format("EVATAR_PORT=~b~n", [Bound]),
    loop(State).

options([], O, Acc) -> {O, lists:reverse(Acc)};
options(["--home", Spec | Rest], O, Acc) -> options(Rest, O#{home => Spec}, Acc);
options(["--robots", Spec | Rest], O, Acc) -> options(Rest, O#{robots => Spec}, Acc);
options(["--home-start", When | Rest], O, Acc) -> options(Rest, O#{start => datetime(When)}, Acc);
options(["--script", Script | Rest], O, Acc) -> options(Rest, O#{script => Script}, Acc);
options(["--speed", N | Rest], O, Acc) -> options(Rest, O#{speed => list_to_integer(N)}, Acc);
options(["--paused" | Rest], O, Acc) -> options(Rest, O#{paused => true}, Acc);
options(["--control", Path | Rest], O, Acc) -> options(Rest, O#{control => Path}, Acc);
options(["--no-stdin" | Rest], O, Acc) -> options(Rest, O#{stdin => false}, Acc);
options(["--" ++ _ = Bad | _], _, _) ->
    io:format(standard_error, "unknown option ~s~n", [Bad]),
    halt(2);
options([Spec | Rest], O, Acc) -> options(Rest, O, [Spec | Acc]).

pairing(Spec) ->
    case string:split(Spec, ":", all) of
        [Id, A, V] when Id =/= "", A =/= "", V =/= "" ->
            {list_to_binary(Id), #{agent_credential => list_to_binary(A),
                                   avatar_credential => list_to_binary(V)}};
        [Id, A, V, T] when Id =/= "", A =/= "", V =/= "" ->
            {list_to_binary(Id), #{agent_credential => list_to_binary(A),
                                   avatar_credential => list_to_binary(V),
                                   feedback_timeout => list_to_integer(T)}};
        _ ->
            io:format(standard_error, "bad pairing ~s~n", [Spec]),
            halt(2)
    end.

start_sim(#{home := Spec} = Opts, Endpoints) ->
    [Pairing, Cred | SpoolParts] = string:split(Spec, ":", all),
    {ok, _} = application:ensure_all_started(avatar_sim),
    Clock = start_clock(Opts),
    Script = case maps:get(script, Opts, "holiday") of
                 "holiday" -> #{script => evatar_demo_holiday:default_script()};
                 "none" -> #{script => []};
                 File -> #{script_file => File}
             end,
    Home = case avatar_sim:start_home(Script#{clock => Clock, seed => 1,
                                             endpoints => Endpoints,
                                             spool => lists:join(":", SpoolParts),
                                             gateways => [#{pairing => list_to_binary(Pairing),
                                                            credential => list_to_binary(Cred)}]}) of
               {ok, H} -> H;
               {error, Why} ->
                   io:format(standard_error, "cannot start the home: ~0p~n", [Why]),
                   halt(2)
           end,
    #{clock => Clock, home => Home, avatar => Home};
start_sim(#{robots := Spec} = Opts, Endpoints) ->
    Robots = [case string:split(R, ":") of
                  [P, C] when P =/= "" -> #{pairing => list_to_binary(P),
                                            credential => list_to_binary(C)};
                  _ -> io:format(standard_error, "bad robot ~s~n", [R]), halt(2)
              end || R <- string:split(Spec, ",", all)],
    {ok, _} = application:ensure_all_started(avatar_sim),
    Clock = start_clock(Opts),
    {ok, Arena} = avatar_sim:start_arena(#{clock => Clock, seed => 1, robots => Robots,
                                           endpoints => Endpoints}),
    #{clock => Clock, arena => Arena, avatar => Arena};
start_sim(_, _Endpoints) ->
    #{}.

start_clock(Opts) ->
    Start = maps:get(start, Opts, evatar_demo_holiday:start_datetime()),
    {ok, Clock} = avatar_sim:start_clock(#{speed => maps:get(speed, Opts, 2), tick => 500,
                                           start => Start,
                                           paused => maps:get(paused, Opts, false)}),
    Clock.

read_stdin(Main) ->
    case io:get_line('') of
        eof -> Main ! stdin_closed;
        {error, _} -> Main ! stdin_closed;
        Line -> Main ! {command, stdio, Line}, read_stdin(Main)
    end.

%% The control socket: a Unix domain socket, one command per connection,
%% served one connection at a time (the commands run one at a time anyway).
control(Path, Main) ->
    case gen_tcp:connect({local, Path}, 0, [local], 1000) of
        {ok, Other} ->
            ok = gen_tcp:close(Other),
            io:format(standard_error, "a node already answers on ~s~n", [Path]),
            halt(2);
        {error, _} ->
            _ = file:delete(Path)
    end,
    {ok, L} = gen_tcp:listen(0, [local, {ifaddr, {local, Path}}, binary, {packet, line},
                                 {packet_size, 4096}, {active, false}]),
    Main ! {control, listening, Path},
    accept(L, Main).

accept(L, Main) ->
    {ok, S} = gen_tcp:accept(L),
    _ = case gen_tcp:recv(S, 0, 5000) of
            {ok, Line} ->
                Main ! {command, {socket, self()}, binary_to_list(Line)},
                receive {reply, Text} -> gen_tcp:send(S, Text) end,
                Main ! {replied, self()};
            {error, _} ->
                ok
        end,
    _ = gen_tcp:close(S),
    accept(L, Main).

loop(S) ->
    receive
        stdin_closed ->
            stop();
        {command, From, Line} ->
            Words = string:lexemes(string:trim(Line), " "),
            {Text, S1} = try command(Words, S) of
                             {ok, Lines, S2} -> {[[L, $\n] || L <- Lines] ++ ["OK\n"], S2};
                             {error, Why} -> {["ERROR ", Why, $\n], S}
                         catch C:R ->
                                 {io_lib:format("ERROR ~0p~n", [{C, R}]), S}
                         end,
            reply(From, Text),
            case S1 of
                #{stopping := true} -> stop();
                _ -> loop(S1)
            end
    end.

reply(stdio, Text) ->
    io:put_chars(Text);
reply({socket, Pid}, Text) ->
    Pid ! {reply, Text},
    receive {replied, Pid} -> ok after 5000 -> ok end.

command(["port", Name, Program | Args], S) ->
    {ok, _} = agent_bridge:start_port(list_to_binary(Name),
                                      #{command => Program, args => Args,
                                        backoff_min => 100, backoff_max => 2000}),
    {ok, [], S};
command(["stop_port", Name], S) ->
    ok = agent_bridge:stop_port(list_to_binary(Name)),
    {ok, [], S};
command(["runs", Name], S) ->
    [Pid] = [P || {{agent_bridge_port, N}, P, _, _} <- supervisor:which_children(agent_bridge_port_sup),
                  N =:= list_to_binary(Name)],
    {ok, [io_lib:format("RUNS ~b", [agent_bridge_port:runs(Pid)])], S};
command(["entities", Pairing], S) ->
    {ok, Registry} = evatar:registry(list_to_binary(Pairing)),
    {ok, [["ENTITIES ", lists:join(" ", [Id || #{entity := Id} <- Registry])]], S};
command(["speed", N], #{clock := Clock} = S) ->
    ok = avatar_sim:pause(Clock),
    ok = avatar_sim:set_speed(Clock, list_to_integer(N)),
    {ok, [], S};
command(["pause"], #{clock := Clock} = S) ->
    ok = avatar_sim:pause(Clock),
    {ok, [], S};
command(["resume"], #{clock := Clock} = S) ->
    ok = avatar_sim:resume(Clock),
    {ok, [], S};
command(["run_until", HHMM], #{clock := Clock} = S) ->
    Target = target_ms(avatar_sim:now(Clock), HHMM),
    ok = avatar_sim:resume(Clock),
    wait_clock(Clock, Target),
    ok = avatar_sim:pause(Clock),
    {ok, [], S};
command(["time"], #{clock := Clock} = S) ->
    #{now := Now, speed := Speed, paused := Paused} = avatar_sim:clock_info(Clock),
    {{Y, Mo, D}, {H, Mi, Sec}} = calendar:system_time_to_universal_time(Now, millisecond),
    {ok, [io_lib:format("TIME ~4..0b-~2..0b-~2..0b ~2..0b:~2..0b:~2..0b ~s speed=~p",
                        [Y, Mo, D, H, Mi, Sec, case Paused of true -> "paused";
                                                              false -> "running" end,
                         Speed])], S};
command(["outcome"], #{home := Home} = S) ->
    #{light_log := Log, emails := Emails, photos := Photos, played := Played} =
        avatar_sim:state(Home),
    {ok, [io_lib:format("LIGHT ~s ~s ~s", [hhmm(T), R, St])
          || #{time := T, room := R, state := St} <- Log]
         ++ [io_lib:format("EMAIL ~s\t~s\t~s", [F, Sub, lists:join(",", A)])
             || #{file := F, subject := Sub, attachments := A} <- Emails]
         ++ [io_lib:format("PHOTO ~s\t~s\t~s", [I, R, F])
             || #{id := I, room := R, file := F} <- Photos]
         ++ [io_lib:format("PLAYED ~s\t~b\t~s", [K, V, W])
             || #{kind := K, volume := V, what := W} <- Played], S};
command(["outcome"], #{arena := Arena} = S) ->
    #{balls := Balls, robots := Robots} = avatar_sim:state(Arena),
    {ok, [io_lib:format("BALL ~s ~b ~b ~s ~s", [C, round(X), round(Y), Z, H])
          || #{colour := C, x := X, y := Y, zone := Z, held_by := H0} <- Balls,
             H <- [case H0 of none -> "none"; I -> integer_to_list(I) end]]
         ++ [io_lib:format("ROBOT ~s ~b ~b ~s", [E, round(X), round(Y), Hold])
             || #{entity := E, x := X, y := Y, holding := Hold} <- Robots], S};
command([Hook, Id | Ms], #{avatar := Avatar} = S)
  when Hook =:= "mute"; Hook =:= "unmute"; Hook =:= "disconnect"; Hook =:= "reconnect";
       Hook =:= "detach"; Hook =:= "attach" ->
    case hook(Hook, Avatar, list_to_binary(Id), Ms) of
        ok -> {ok, [], S};
        {error, Why} -> {error, io_lib:format("~s ~s: ~0p", [Hook, Id, Why])}
    end;
command(["links"], #{avatar := Avatar} = S) ->
    {ok, [io_lib:format("LINK ~s ~s ~s routes=~b muted=~s detached=~s",
                        [E, P, St, R, lists:join(",", M), lists:join(",", D)])
          || #{entity := E, pairing := P, state := St, routes := R, muted := M,
               detached := D} <- avatar_sim:links(Avatar)], S};
command(["stop"], S) ->
    {ok, [], S#{stopping => true}};
command(["kill", I], #{ospids := OsPids} = S) ->
    _ = os:cmd("kill -9 " ++ lists:nth(list_to_integer(I), OsPids)),
    {ok, [], S};
command(["freeze", I], #{ospids := OsPids} = S) ->
    OsPid = lists:nth(list_to_integer(I), OsPids),
    _ = os:cmd("kill -STOP " ++ OsPid),
    %% kill -9 when this script ends: a stopped node would not see its
    %% control connection close.
    put(frozen, [OsPid | case get(frozen) of undefined -> []; F -> F end]),
    {ok, [], S};
command(["ha", Pairing], #{nodes := Nodes} = S) ->
    Id = list_to_binary(Pairing),
    {ok, [io_lib:format("HA ~b ~s ~b", [I, Role, Epoch])
          || {I, {P, _}} <- lists:zip(lists:seq(1, length(Nodes)), Nodes),
             {ok, #{role := Role, epoch := Epoch}} <- [catch peer:call(P, evatar, ha_status,
                                                                      [Id], 2000)]], S};
command(["outcome"], _S) ->
    {error, "outcome needs the home or the robots (--home, --robots)"};
command([Clock | _], _S)
  when Clock =:= "time"; Clock =:= "pause"; Clock =:= "resume"; Clock =:= "speed";
       Clock =:= "run_until" ->
    {error, "no simulated clock on this node (--home or --robots)"};
command([Hook | _], _S)
  when Hook =:= "mute"; Hook =:= "unmute"; Hook =:= "disconnect"; Hook =:= "reconnect";
       Hook =:= "detach"; Hook =:= "attach"; Hook =:= "links" ->
    {error, "no simulated Avatar on this node (--home or --robots)"};
command(Other, _S) ->
    {error, io_lib:format("unknown command ~0p", [lists:join(" ", Other)])}.

hook("mute", A, C, []) -> avatar_sim:mute(A, C);
hook("unmute", A, C, []) -> avatar_sim:unmute(A, C);
hook("disconnect", A, E, []) -> avatar_sim:disconnect(A, E);
hook("disconnect", A, E, [Ms]) -> avatar_sim:disconnect(A, E, list_to_integer(Ms));
hook("reconnect", A, E, []) -> avatar_sim:reconnect(A, E);
hook("detach", A, C, []) -> avatar_sim:detach_device(A, C);
hook("attach", A, C, []) -> avatar_sim:attach_device(A, C);
hook(_, _, _, _) -> {error, too_many_arguments}.

stop() ->
    _ = [file:delete(Path) || Path <- [get(control)], Path =/= undefined],
    _ = [os:cmd("kill -9 " ++ OsPid) || OsPid <- case get(frozen) of
                                                     undefined -> [];
                                                     F -> F
                                                 end],
    halt(0).

%% A cluster of N peer nodes, set up as apps/evatar/test/evatar_ha_SUITE does.
cluster(N, Args) ->
    {Opts, Specs} = options(Args, #{}, []),
    Pairings = [pairing(Spec) || Spec <- Specs],
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
    %% The simulated Avatar runs here, outside the cluster, with every
    %% node's endpoint: killing a node leaves it to join another.
    Sim = start_sim(Opts, [{{127, 0, 0, 1}, Pt} || Pt <- Ports]),
    io:format("EVATAR_PORTS=~s~n", [lists:join(",", [integer_to_list(Pt) || Pt <- Ports])]),
    io:format("EVATAR_PORT=~b~n", [hd(Ports)]),
    OsPids = [peer:call(P, os, getpid, []) || {P, _} <- Started],
    Main = self(),
    _ = spawn_link(fun() -> read_stdin(Main) end),
    loop(Sim#{nodes => Started, ospids => OsPids}).

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
