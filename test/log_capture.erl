%% @doc Test support. A logger handler that keeps every event it is given in
%% an ETS table of the node it runs on, installed next to the node's
%% `default' handler with that handler's filters, filter_default and level,
%% so that it receives exactly the events the configured handler writes.
%% Each event is also run through the default handler's formatter, to see
%% the line it makes. Internal to the root test/ directory.
-module(log_capture).

-export([install/0, uninstall/0, events/0, marker/1]).
-export([log/2]).

-define(TAB, log_capture).
-define(ID, log_capture).

%% @doc Installs the capturing handler on this node (again: forgets what an
%% earlier one kept). The table belongs to a process of its own, since the
%% caller may be a short-lived rpc process.
-spec install() -> ok.
install() ->
    _ = uninstall(),
    Self = self(),
    Owner = spawn(fun() ->
                          _ = ets:new(?TAB, [named_table, public, ordered_set]),
                          Self ! {?MODULE, ready},
                          receive stop -> ok end
                  end),
    receive {?MODULE, ready} -> ok end,
    true = ets:insert(?TAB, {owner, Owner}),
    {ok, Default} = logger:get_handler_config(default),
    Config = maps:with([level, filters, filter_default, formatter], Default),
    ok = logger:add_handler(?ID, ?MODULE, Config).

%% @doc Removes the handler and its table.
-spec uninstall() -> ok.
uninstall() ->
    _ = logger:remove_handler(?ID),
    case ets:whereis(?TAB) of
        undefined ->
            ok;
        _ ->
            [{owner, Owner}] = ets:lookup(?TAB, owner),
            Ref = monitor(process, Owner),
            Owner ! stop,
            receive {'DOWN', Ref, process, Owner, _} -> ok end
    end.

%% @doc Every event kept so far, in the order they were logged, each as
%% `#{level, msg, meta, line}' where `line' is what the default handler's
%% formatter made of it.
-spec events() -> [map()].
events() ->
    [E || {{event, _}, E} <- ets:tab2list(?TAB)].

%% @doc Logs a notice whose report is `#{what => log_capture_marker, id =>
%% Id}': once it is kept, every event logged before it by a process that
%% has finished logging is kept too. It is logged by a process of this
%% node's own (an rpc's process has the caller's group leader, and the
%% configured filters leave such events to the caller's node).
-spec marker(term()) -> ok.
marker(Id) ->
    {Pid, Ref} = spawn_monitor(fun() ->
                                       true = group_leader(whereis(user), self()),
                                       logger:notice(#{what => log_capture_marker, id => Id})
                               end),
    receive {'DOWN', Ref, process, Pid, normal} -> ok end.

%% @private The handler callback, run by the process that logs.
-spec log(logger:log_event(), logger:handler_config()) -> ok.
log(Event, #{formatter := {Mod, FConfig}}) ->
    Line = unicode:characters_to_binary(Mod:format(Event, FConfig)),
    true = ets:insert(?TAB, {{event, erlang:unique_integer([monotonic])},
                             (maps:with([level, msg, meta], Event))#{line => Line}}),
    ok.
